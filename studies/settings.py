"""An env setting as one command-line word, so that a study's rows name the setting they were played at.

``"rl_lite,link_range_m=2.5"`` is the preset ``rl_lite`` with one override; the same text is each row's
``setting``, so a rerun finds the rows it already has.
"""

from __future__ import annotations


def parse_setting(text: str) -> tuple[str, dict[str, int | float | str]]:
    """``"rl,frames_per_agent=60,scene=office0"`` -> ``("rl", {"frames_per_agent": 60, "scene": "office0"})``:
    each value an int if it reads as one, else a float, else the text."""
    preset, *items = text.split(",")
    overrides: dict[str, int | float | str] = {}
    for item in items:
        key, _, value = item.partition("=")
        overrides[key] = _number(value)
    return preset, overrides


def _number(value: str) -> int | float | str:
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            continue
    return value
