"""The console's snapshot carries the budget for calls before authentication (coordinator/admission.py)."""
from __future__ import annotations

from coordinator.admission import MIB
from coordinator.api import AdmissionFigures, RigStatus
from coordinator.console.live import _before_auth


def test_the_snapshot_names_refused_and_malformed_calls_and_the_budget():
    st = RigStatus(rig_id="x", rig_name="t", admission=AdmissionFigures(
        in_flight_calls=2, in_flight_bytes=3 * MIB, peak_bytes=16 * MIB, admitted=40, refused=300, malformed=7,
        max_calls=64, max_bytes=16 * MIB, max_calls_per_address=16, max_bytes_per_address=4 * MIB))
    d = _before_auth(st)
    assert (d["refused"], d["malformed"], d["admitted"], d["in_flight_calls"]) == (300, 7, 40, 2)
    assert (d["in_flight_mib"], d["peak_mib"], d["max_mib"], d["max_mib_per_address"]) == (3.0, 16.0, 16.0, 4.0)
    assert d["max_calls"] == 64 and d["max_calls_per_address"] == 16
