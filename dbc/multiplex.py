"""Multiplexed messages: which pages a message has, and values that select a defined one.

A multiplexed DBC message carries one page per frame: its multiplexer signal (``M``) selects
which of the multiplexed signals (``m0``, ``m1``, ...) the frame holds; extended multiplexing
(``SG_MUL_VAL_``) nests multiplexers. cantools describes this in ``Message.signal_tree``: a list
whose dict entries map a multiplexer's name to ``{raw value: [signals or nested dicts]}``.

A page here is one complete choice of every multiplexer a frame needs: a mapping from
multiplexer name to raw value. A transmitter that sends "every page in turn" sends the pages of
`pages` one after the other.
"""

from __future__ import annotations

from typing import Any

__all__ = ["pages", "page_of", "select_defined_page", "multiplexer_names"]


def multiplexer_names(message: Any) -> set[str]:
    """Names of the multiplexer signals of a cantools message (empty when it has none)."""
    return {s.name for s in message.signals if s.is_multiplexer}


def pages(message: Any) -> list[dict[str, int]]:
    """Every page of a multiplexed cantools message, in the order of its multiplexer values
    (nested multiplexers vary fastest): each a mapping multiplexer name -> raw value. A message
    without multiplexer has no pages (empty list)."""
    result: list[dict[str, int]] = [{}]
    for entry in message.signal_tree:
        if isinstance(entry, dict):
            result = [{**a, **b} for a in result for b in _tree_pages(entry)]
    return [] if result == [{}] else result


def _tree_pages(tree: dict[str, Any]) -> list[dict[str, int]]:
    out: list[dict[str, int]] = []
    for mux_name, branches in tree.items():
        for raw in sorted(branches):
            sub: list[dict[str, int]] = [{mux_name: raw}]
            for entry in branches[raw]:
                if isinstance(entry, dict):
                    sub = [{**a, **b} for a in sub for b in _tree_pages(entry)]
            out.extend(sub)
    return out


def select_defined_page(message: Any, values: dict[str, Any]) -> None:
    """Make every multiplexer in ``values`` (physical values or choice names) select a defined
    branch: one whose value selects none (its start value may not) is set to the lowest defined
    raw value."""
    for tree in message.signal_tree:
        if isinstance(tree, dict):
            _fix_tree(message, tree, values)


def _raw_selector(sig: Any, value: Any) -> int | None:
    """The raw value a multiplexer's physical value or choice name selects (None: none)."""
    try:
        if isinstance(value, str):
            return int(sig.conversion.choice_to_number(value))
        return round(sig.conversion.scaled_to_raw(value))
    except Exception:
        return None


def _fix_tree(message: Any, tree: dict[str, Any], values: dict[str, Any]) -> None:
    for mux_name, branches in tree.items():
        sig = message.get_signal_by_name(mux_name)
        rawnum = _raw_selector(sig, values.get(mux_name))
        if rawnum not in branches:
            rawnum = min(branches)
            values[mux_name] = sig.conversion.raw_to_scaled(rawnum, False)
        for sub in branches[rawnum]:
            if isinstance(sub, dict):
                _fix_tree(message, sub, values)


def page_of(message: Any, values: dict[str, Any]) -> dict[str, int]:
    """The page ``values`` select (multiplexer name -> raw value) — only the multiplexers the
    selection reaches."""
    out: dict[str, int] = {}
    for tree in message.signal_tree:
        if isinstance(tree, dict):
            _page_of_tree(message, tree, values, out)
    return out


def _page_of_tree(message: Any, tree: dict[str, Any], values: dict[str, Any], out: dict[str, int]) -> None:
    for mux_name, branches in tree.items():
        rawnum = _raw_selector(message.get_signal_by_name(mux_name), values.get(mux_name))
        if rawnum is None:
            continue
        out[mux_name] = rawnum
        for sub in branches.get(rawnum, ()):
            if isinstance(sub, dict):
                _page_of_tree(message, sub, values, out)
