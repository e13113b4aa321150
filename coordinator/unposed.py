"""The one warning for content shown on slots without a pose, worded once for the command line
(``shadowless show`` and ``play`` print it on stderr) and the console (the page shows it beside
Show and Play, from ``status``), so the two say the same."""
from __future__ import annotations

from typing import Sequence

from protos.wording import count


def unposed_warning(unposed: Sequence[str]) -> str:
    """One line naming the slots without a pose ("" when there are none): content is warped by
    each slot's pose, so those projectors show black, and how to give them one."""
    if not unposed:
        return ""
    n = len(unposed)
    return (f"{count(n, 'slot')} {'has' if n == 1 else 'have'} no pose and show{'s' if n == 1 else ''} "
            f"black: {', '.join(unposed)} (calibrate {'it' if n == 1 else 'them'} with `shadowless calibrate`, "
            "or set one with `shadowless configure --slot S --homography H`)")
