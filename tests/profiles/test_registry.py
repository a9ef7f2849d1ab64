"""How profile packages make themselves known: each package's ``kind`` module lists its kinds in
``KINDS``; the registry reads the built-in packages and the ``canstack.profiles`` entry points."""

from __future__ import annotations

import importlib
import importlib.metadata
import sys
import types

import pytest

from profiles import registry
from profiles.csma import CsmaProfile


@pytest.fixture
def empty_registry(monkeypatch):
    """A registry that has read nothing yet (the real one is restored after the test)."""
    monkeypatch.setattr(registry, "_KINDS", {})
    monkeypatch.setattr(registry, "_loaded", False)


def entry_points_with(monkeypatch, *eps):
    real = importlib.metadata.entry_points

    def fake(**kw):
        if kw.get("group") == registry.ENTRY_POINT_GROUP:
            return list(eps)
        return real(**kw)

    monkeypatch.setattr(importlib.metadata, "entry_points", fake)


def third_party(monkeypatch, kinds):
    mod = types.ModuleType("third_party_profile.kind")
    mod.KINDS = kinds
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    return mod


def build(node, decl, context):
    return CsmaProfile(node, decl, context)


def test_every_built_in_package_declares_its_kinds_in_its_kind_module(empty_registry):
    names = {}
    for module in registry.BUILT_IN:
        package = module.rpartition(".")[0]
        assert module == f"{package}.kind"
        names[package] = [k.name for k in importlib.import_module(module).KINDS]
    assert names == {
        "profiles.csma": ["csma"],
        "profiles.tdma": ["tdma"],
        "profiles.canopen": ["canopen", "canopen-master"],
        "profiles.polling": ["master", "slave"],
    }
    # the registry holds exactly these, every one from its package's kind module
    kinds = registry.profile_kinds()
    assert sorted(kinds) == sorted(n for ns in names.values() for n in ns)
    for package, ns in names.items():
        for n in ns:
            assert kinds[n].build.__module__ == f"{package}.kind"


def test_an_installed_distribution_adds_a_profile_through_the_entry_point_group(empty_registry, monkeypatch):
    mine = registry.ProfileKind(name="mine", build=build, description="a third party's")
    third_party(monkeypatch, (mine,))
    ep = importlib.metadata.EntryPoint("mine", "third_party_profile.kind:KINDS", registry.ENTRY_POINT_GROUP)
    entry_points_with(monkeypatch, ep)
    kinds = registry.profile_kinds()
    assert kinds["mine"] is mine and "csma" in kinds
    # a scenario may name it now
    from profiles.pipeline.scenario import parse_scenario

    sc = parse_scenario(
        {"bus": {"bitrate": 500000, "duration": 0.01}, "nodes": [{"name": "a", "profile": "mine", "messages": []}]}
    )
    assert sc.nodes[0].profile == "mine"


def test_an_entry_point_may_name_one_kind(empty_registry, monkeypatch):
    mine = registry.ProfileKind(name="single", build=build)
    third_party(monkeypatch, mine)
    entry_points_with(
        monkeypatch,
        importlib.metadata.EntryPoint("single", "third_party_profile.kind:KINDS", registry.ENTRY_POINT_GROUP),
    )
    assert registry.profile_kind("single") is mine


def test_an_entry_point_that_names_no_kind_is_an_error_naming_it(empty_registry, monkeypatch):
    third_party(monkeypatch, ["not a kind"])
    entry_points_with(
        monkeypatch,
        importlib.metadata.EntryPoint("broken", "third_party_profile.kind:KINDS", registry.ENTRY_POINT_GROUP),
    )
    with pytest.raises(ValueError, match=r"entry point broken = 'third_party_profile.kind:KINDS'.*not a ProfileKind"):
        registry.profile_kinds()
    assert registry._loaded is False  # the next use tries again rather than running on half a registry


def test_an_entry_point_that_cannot_be_loaded_is_an_error_naming_it(empty_registry, monkeypatch):
    entry_points_with(
        monkeypatch, importlib.metadata.EntryPoint("gone", "no_such_module_here.kind:KINDS", registry.ENTRY_POINT_GROUP)
    )
    with pytest.raises(ValueError, match=r"entry point gone = .*cannot load it \(ModuleNotFoundError"):
        registry.profile_kinds()


def test_a_second_kind_of_the_same_name_is_refused(empty_registry, monkeypatch):
    third_party(monkeypatch, (registry.ProfileKind(name="csma", build=build),))
    entry_points_with(
        monkeypatch,
        importlib.metadata.EntryPoint("clash", "third_party_profile.kind:KINDS", registry.ENTRY_POINT_GROUP),
    )
    with pytest.raises(ValueError, match="profile 'csma' is registered twice"):
        registry.profile_kinds()
