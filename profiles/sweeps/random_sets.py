"""Random message sets for the studies.

`generate_set`: deadlines equal periods, identifiers are distinct random
11-bit values (priority by identifier, as CAN arbitrates) handed out in deadline-monotonic order
unless ``priorities="random"``, DLCs uniform in 0..8, messages dealt
to nodes ``per_node`` at a time in random order. The utilisation U counts worst-case frames
(Davis et al. 2007, eq. 1). Two generators, because on CAN the two usual ingredients cannot both
hold: a frame's transmission time is fixed by its DLC (55 to 135 bit times, standard
identifiers), so once a UUniFast share u_i and a log-uniform period T_i are drawn, C_i = u_i T_i
is almost never the length of any frame.

- ``uunifast`` (default): UUniFast (Bini and Buttazzo, "Measuring the performance of
  schedulability tests", Real-Time Systems 30, 2005) splits U into u_1..u_n without bias; each
  message's period follows from its frame, T_i = C_i / u_i, on the bus's fixed bit rate. A set
  with a period outside ``period_range_ms`` is drawn again (UUniFast-Discard), so the range
  bounds the periods; they are not log-uniform in it.
- ``loguniform``: periods log-uniform in ``period_range_ms`` (Emberson, Stafford, Davis 2010);
  the bit rate of the set is then the one that makes its utilisation U (b = Σ bits_i / T_i / U),
  which is how a fixed set of periods and frames reaches a given load.

The same set number draws the same random numbers at every utilisation (common random numbers):
with ``uunifast`` a set at a higher U is the same set with shorter periods, so the curves differ
between points by the utilisation, not by sampling noise.
"""

from __future__ import annotations

import math
import random

from profiles.analysis.rta import frame_bits_worst
from profiles.message_set import MessageSet, StudyMessage

__all__ = ["uunifast", "generate_set", "GENERATORS", "PRIORITIES", "PERIOD_RANGES_MS", "MAX_DRAWS"]

GENERATORS = ("uunifast", "loguniform")
PRIORITIES = ("deadline", "random")
PERIOD_RANGES_MS = {"uunifast": (0.1, 1000.0), "loguniform": (10.0, 1000.0)}
"""Default period ranges (ms). UUniFast-Discard: periods come out at C_i / u_i >= C_i / U, so the
lower bound rarely matters; the upper one keeps sets with a nearly idle message (and a long
simulation) out. Log-uniform: a range whose bit rates stay within 1 kbit/s .. 1 Mbit/s for 10
messages at 10 .. 100 %."""
MAX_DRAWS = 10_000  # UUniFast-Discard: draws before a set is given up on (a range that cannot be met)


def uunifast(n: int, total: float, rng: random.Random) -> list[float]:
    """UUniFast (Bini and Buttazzo 2005): ``n`` utilisations summing to ``total``, uniformly
    distributed over that simplex. u_i = s_i − s_{i+1} with s_{i+1} = s_i · r^(1/(n−i)),
    r uniform in [0, 1)."""
    if n < 1:
        raise ValueError(f"uunifast: n {n} must be >= 1")
    out: list[float] = []
    s = total
    for i in range(1, n):
        nxt = s * rng.random() ** (1.0 / (n - i))
        out.append(s - nxt)
        s = nxt
    out.append(s)
    return out


def _skeleton(rng: random.Random, n: int, per_node: int) -> tuple[list[int], list[int], list[str]]:
    """DLCs, distinct identifiers and nodes of ``n`` messages (``per_node`` to a node, dealt in a
    random order)."""
    dlcs = [rng.randint(0, 8) for _ in range(n)]
    ids = rng.sample(range(0x800), n)
    order = list(range(n))
    rng.shuffle(order)
    nodes = [""] * n
    for pos, i in enumerate(order):
        nodes[i] = f"node{pos // per_node + 1}"
    return dlcs, ids, nodes


def generate_set(
    rng: random.Random,
    *,
    messages: int,
    utilisation: float,
    bitrate: int = 500_000,
    per_node: int = 1,
    period_range_ms: tuple[float, float] | None = None,
    generator: str = "uunifast",
    priorities: str = "deadline",
    seed: int = 0,
) -> MessageSet:
    """A random message set of utilisation ``utilisation`` (see the module docstring for the two
    generators). ``priorities``: ``deadline`` hands the random identifiers out in deadline-monotonic
    order (the shortest deadline gets the lowest identifier, the usual CAN assignment), ``random``
    keeps them as drawn (priorities in no relation to the deadlines). Messages are declared node
    by node in a random order (the order a FIFO queue sees them released together). ValueError when the range cannot be met in `MAX_DRAWS` draws or
    the bit rate a ``loguniform`` set needs is outside 1 kbit/s .. 1 Mbit/s."""
    if generator not in GENERATORS:
        raise ValueError(f"generator {generator!r}: one of {', '.join(GENERATORS)}")
    if priorities not in PRIORITIES:
        raise ValueError(f"priorities {priorities!r}: one of {', '.join(PRIORITIES)}")
    if not 0 < utilisation <= 1.5:
        raise ValueError(f"utilisation {utilisation!r}: must be > 0 and at most 1.5")
    if messages < 1 or per_node < 1:
        raise ValueError("a set needs at least one message and one message per node")
    lo_ms, hi_ms = period_range_ms or PERIOD_RANGES_MS[generator]
    if not 0 < lo_ms < hi_ms:
        raise ValueError(f"period range {lo_ms}..{hi_ms} ms: must be 0 < min < max")
    lo, hi = round(lo_ms * 1e6), round(hi_ms * 1e6)
    for _ in range(MAX_DRAWS):
        if generator == "uunifast":
            shares = uunifast(messages, utilisation, rng)
            dlcs, ids, nodes = _skeleton(rng, messages, per_node)
            rate = bitrate
            if min(shares) <= 0:
                continue
            # whole ns, rounded down: the set's utilisation is never below the target (at 100 % a
            # period rounded up would leave a busy period that converges after millions of steps)
            periods = [math.floor(frame_bits_worst(d, False) * 1e9 / rate / u) for d, u in zip(dlcs, shares)]
        else:
            periods = [round(math.exp(rng.uniform(math.log(lo), math.log(hi)))) for _ in range(messages)]
            dlcs, ids, nodes = _skeleton(rng, messages, per_node)
            bits_per_s = sum(frame_bits_worst(d, False) * 1e9 / t for d, t in zip(dlcs, periods))
            rate = math.floor(bits_per_s / utilisation)  # rounded up, the utilisation would fall below U
            if not 1_000 <= rate <= 1_000_000:
                raise ValueError(
                    f"a log-uniform set at U = {utilisation:g} needs {rate:,} bit/s, outside "
                    "1 kbit/s .. 1 Mbit/s: change the period range or the number of messages"
                )
        if all(lo <= t <= hi for t in periods):
            break
    else:
        raise ValueError(
            f"no UUniFast set of {messages} messages at U = {utilisation:g} has every period in "
            f"{lo_ms:g}..{hi_ms:g} ms at {bitrate:,} bit/s ({MAX_DRAWS:,} draws): widen the range"
        )
    if priorities == "deadline":  # deadlines = periods: the shortest period gets the lowest identifier
        by_deadline = sorted(range(messages), key=lambda k: (periods[k], k))
        drawn = sorted(ids)
        for rank, k in enumerate(by_deadline):
            ids[k] = drawn[rank]
    msgs = [StudyMessage(f"m{k + 1:02d}", nodes[k], ids[k], dlcs[k], periods[k], periods[k]) for k in range(messages)]
    msgs.sort(key=lambda m: (int(m.node[4:]), rng.random()))
    longest = max(m.period_ns for m in msgs)
    return MessageSet(rate, tuple(msgs), duration_s=2 * longest / 1e9, seed=seed)
