"""Constructor options as a scenario file gives them (TOML tables): accepted forms, and every
refusal naming the option, the value and the rule."""

import pytest
import tomllib

from profiles.canopen import CanopenDevice, CanopenMaster, EdsError
from profiles.canopen.options import DeviceOptions, MasterOptions, parse_mapping_entry, parse_object_key


def test_a_toml_table_configures_a_device(bus):
    table = tomllib.loads("""
        heartbeat_ms = 100
        sync_window_us = 400
        heartbeat_consumers = { "3" = 150 }
        [tpdo.1]
        transmission_type = 2
        mapping = ["0x2003:0/16", "0x2002:0/32"]
        [tpdo.2]
        transmission_type = 255
        inhibit_100us = 10
        event_timer_ms = 50
        [rpdo.4]
        valid = true
        [values]
        "0x2001:1" = 12
    """)
    d = CanopenDevice(bus.node("d"), 4, **table)
    assert d.read(0x1017) == 100 and d.read(0x1007) == 400 and d.read(0x1016, 1) == (3 << 16) | 150
    assert [(m.index, m.size) for m in d.tpdo(1).mapped] == [(0x2003, 2), (0x2002, 4)]
    assert d.tpdo(2).inhibit_ns == 1_000_000 and d.tpdo(2).event_ns == 50_000_000
    assert d.rpdo(4).valid and d.read(0x2001, 1) == 12


def test_a_toml_table_configures_a_master(bus):
    table = tomllib.loads("""
        nodes = [1, 2, 3]
        sync_period_us = 1000
        heartbeat_ms = 100
        [configure.2]
        "0x1800:2" = 4
    """)
    m = CanopenMaster(bus.node("m"), **table)
    assert m.options.heartbeat_consumer_ms == 151 and m.options.configure == {2: {(0x1800, 2): 4}}


@pytest.mark.parametrize(
    "options, message",
    [
        ({"heartbeat_ms": 70000}, r"heartbeat_ms 70000: 0\.\.65535 \(0x1017"),
        ({"heartbeat_ms": "fast"}, r"heartbeat_ms 'fast': an integer"),
        ({"heartbeat_ms": True}, r"heartbeat_ms True: an integer"),
        ({"sync_overflow": 1}, r"sync_overflow 1: the SYNC counter overflow value is 0 or 2\.\.240"),
        ({"sync_cob_id": 0x701}, r"sync_cob_id 0x701: a restricted CAN-ID"),
        ({"heartbeat_consumers": {"0": 100}}, r"heartbeat_consumers node-ID 0: .*1\.\.127"),
        ({"heartbeat_consumers": {"1": 100, "2": 100, "3": 100, "4": 100, "5": 100}}, r"5 nodes, .* 0x1016 has 4"),
        ({"tpdo": {"1": {"transmission_type": 245}}}, r"tpdo\.1\.transmission_type 245: reserved for a TPDO"),
        ({"rpdo": {"1": {"transmission_type": 252}}}, r"rpdo\.1\.transmission_type 252: reserved for an RPDO"),
        ({"tpdo": {"1": {"mapping": ["0x1017:0/16"]}}}, r"tpdo\.1\.mapping: SDO abort 0x06040041.*not PDO-mappable"),
        (
            {"tpdo": {"1": {"mapping": ["0x2002:0/32", "0x2002:0/32", "0x2000:0/8"]}}},
            r"tpdo\.1\.mapping: SDO abort 0x06040042",
        ),
        ({"tpdo": {"1": {"mapping": ["2002/32"]}}}, r"'2002/32': a mapping entry is 'INDEX:SUB/BITS'"),
        ({"tpdo": {"9": {"valid": False}}}, r"tpdo\.9: the dictionary has no TPDO9"),
        ({"tpdo": {"1": {"speed": 1}}}, r"tpdo\.1: unknown key 'speed'"),
        ({"rpdo": {"1": {"inhibit_100us": 1}}}, r"rpdo\.1: unknown key 'inhibit_100us'"),
        ({"tpdo": {"1": {"cob_id": 0x605}}}, r"tpdo\.1\.cob_id 0x605: a restricted CAN-ID"),
        ({"values": {"0x2003": 5000}}, r"values\.0x2003:0 5000: SDO abort 0x06090031"),
        ({"values": {"0x9999": 1}}, r"values\.0x9999:0: the dictionary has no object 0x9999:0"),
        ({"values": {"index": 1}}, r"values key 'index': an object is 'INDEX' or 'INDEX:SUB'"),
        ({"sdo_block_size": 0}, r"sdo_block_size 0: 1\.\.127"),
        ({"boot_delay_ms": -1}, r"boot_delay_ms -1: a number >= 0"),
        ({"colour": "red"}, r"unknown option 'colour' for a CANopen device; known: "),
    ],
)
def test_bad_device_options_name_the_option_and_the_rule(bus, options, message):
    with pytest.raises(ValueError, match=message):
        CanopenDevice(bus.node("d"), 4, **options)


@pytest.mark.parametrize("node_id", [0, 128, -1, "5", 5.0, True])
def test_bad_node_ids(bus, node_id):
    with pytest.raises(ValueError, match=r"node_id .*: a CANopen node-ID is an integer 1\.\.127"):
        CanopenDevice(bus.node("d"), node_id)


@pytest.mark.parametrize(
    "options, message",
    [
        ({}, r"nodes: the master needs the list of node-IDs"),
        ({"nodes": []}, r"nodes \[\]: a non-empty list"),
        ({"nodes": [1, 1]}, r"a node-ID appears twice"),
        ({"nodes": [1, 200]}, r"nodes 200: .*1\.\.127"),
        ({"nodes": [1], "configure": {"2": {"0x1017": 1}}}, r"configure names node 2, which is not in nodes \[1\]"),
        ({"nodes": [1], "sync_overflow": 250}, r"sync_overflow 250: 0\.\.240"),
        ({"nodes": [1], "speed": 1}, r"unknown option 'speed' for a CANopen master"),
    ],
)
def test_bad_master_options(bus, options, message):
    with pytest.raises(ValueError, match=message):
        CanopenMaster(bus.node("m"), **options)


def test_an_eds_whose_valid_pdo_cannot_be_mapped_is_an_eds_error(bus, tmp_path):
    from profiles.canopen.dictionary import DEFAULT_EDS

    text = DEFAULT_EDS.read_text().replace(
        "[1A00sub1]\nParameterName=Application object 1\nObjectType=0x7\n"
        "DataType=0x0007\nAccessType=rw\nDefaultValue=0x20020020",
        "[1A00sub1]\nParameterName=Application object 1\nObjectType=0x7\n"
        "DataType=0x0007\nAccessType=rw\nDefaultValue=0x10170010",
    )
    path = tmp_path / "bad.eds"
    path.write_text(text)
    with pytest.raises(EdsError, match=r"bad\.eds: TPDO1 is valid but its mapping 0x1A00 cannot be used"):
        CanopenDevice(bus.node("d"), 4, path)


def test_parsers_accept_every_documented_form():
    assert parse_object_key("k", "0x2001:1") == (0x2001, 1) == parse_object_key("k", [0x2001, 1])
    assert parse_object_key("k", "4096") == (0x1000, 0)
    assert parse_mapping_entry("m", "0x2002:0/32") == 0x2002_0020 == parse_mapping_entry("m", [0x2002, 0, 32])
    assert parse_mapping_entry("m", 0x2002_0020) == 0x2002_0020
    assert DeviceOptions.parse({"heartbeat_consumers": [[3, 100]]}).heartbeat_consumers == {3: 100}
    assert MasterOptions.parse({"nodes": ["3"]}).nodes == [3]


def test_node_id_and_eds_come_from_the_table_too(bus):
    from profiles.canopen.dictionary import DEFAULT_EDS

    table = tomllib.loads(f'node_id = 7\neds = "{DEFAULT_EDS}"\nheartbeat_ms = 10\n')
    d = CanopenDevice(bus.node("d"), **table)
    assert d.node_id == 7 and d.read(0x1017) == 10 and d.read(0x1014) == 0x87
