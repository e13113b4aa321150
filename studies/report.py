"""How the studies' analyses print numbers: JSON that strict parsers accept, text that keeps
the significant digits of small p values.

* JSON carries every float at full precision (Python's shortest round-trip form); a value that
  is not a finite number (an undefined ratio, a statistic that does not apply) becomes ``null``,
  never ``NaN`` or ``Infinity``, which are not JSON. The reason a value is undefined travels
  beside it, in words.
* Text prints a p value with four decimals down to 0.001, below that in scientific notation
  with two significant digits (``3.2e-07``): ``0.0000`` says nothing.
"""
from __future__ import annotations

import json
import math
from typing import Any


def finite_or_none(x: Any) -> Any:
    """``x`` with every float that is NaN or infinite replaced by None, through dicts, lists
    and tuples (numpy scalars become Python numbers)."""
    if isinstance(x, dict):
        return {str(k): finite_or_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite_or_none(v) for v in x]
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if hasattr(x, "item") and not isinstance(x, (int, float)):   # a numpy scalar
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def dumps(doc: Any) -> str:
    """``doc`` as indented JSON, full precision, non-finite numbers as null (``allow_nan=False``
    guarantees that nothing else slips through)."""
    return json.dumps(finite_or_none(doc), indent=2, allow_nan=False)


def p_text(p: float) -> str:
    """A p value for a table: ``0.0123``, ``3.2e-07``, ``< 1e-300`` for one that underflowed, ``-``
    when undefined."""
    if p is None or not math.isfinite(p):
        return "-"
    if p >= 1e-3:
        return f"{p:.4f}"
    if p == 0.0:
        return "< 1e-300"
    return f"{p:.2g}"


def num_text(x: float, fmt: str = ".3f") -> str:
    """A number for a table, ``-`` when undefined."""
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)
