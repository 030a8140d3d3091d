"""What a setup's program claims to finish, read from its `setup.json` entry: the patches it lists,
each whole or on the parameter rectangles named under `partial` (the rest of such a patch is left,
with the reason, and verify holds the program to the rectangles alone)."""

from __future__ import annotations

from typing import Any

from cam.io.errors import ReadError
from cam.spline.geometry import Patch
from cam.spline.knots import sub_surface

__all__ = ["claimed_patches"]


def claimed_patches(entry: dict[str, Any], part: list[Patch]) -> list[Patch]:
    """The machined patches of one `setup.json` setup entry, cut to their claimed rectangles.

    part: every patch of the part in the setup's machine frame; returns those the entry lists under
    `patches`, a patch claimed on k rectangles as k patches. `ReadError` when a `partial` entry is not a
    parameter rectangle inside its patch.

    Parameters
    ----------
    entry : dict
        One setup of `setup.json`: ``"patches"`` (patch ids) and, optionally, ``"partial"``
        (``{"patch": id, "region": [u0, u1, v0, v1]}`` per claimed rectangle).
    part : list of Patch
        Every patch of the part in the setup's machine frame.

    Returns
    -------
    list of Patch
        The listed patches in the order of `part`, each whole or as one patch per claimed rectangle
        (an exact sub-surface with the same id and sign).

    Raises
    ------
    ReadError
        When a `partial` entry is not a parameter rectangle inside its patch.
    """
    listed = {int(i) for i in entry.get("patches") or []}
    machined = [p for p in part if p.id in listed]
    try:
        claims: dict[int, list] = {}
        for q in entry.get("partial") or []:
            claims.setdefault(int(q["patch"]), []).append(tuple(float(x) for x in q["region"]))
        return [q for p in machined for q in
                ([Patch(p.id, sub_surface(p.surface, box), p.sign) for box in claims[p.id]]
                 if p.id in claims else [p])]
    except (KeyError, TypeError, ValueError) as exc:
        raise ReadError(f"setup {entry.get('id')} in setup.json has a 'partial' entry that is not a parameter "
                        f"rectangle inside its patch: {exc}") from exc
