"""`shadowless bench console_login`, small: guessers on several loopback addresses get no more
tries than the global budget, and a browser with a device cookie gets in at its first try."""
from __future__ import annotations

import argparse
import json

import bench.console_login


def test_a_small_distributed_attack_stays_within_the_budget(capsys):
    parser = argparse.ArgumentParser()
    bench.console_login.configure(parser)
    # the budget of 30 is spent within a second of the attack; the operator tries from its second on
    assert bench.console_login.run(parser.parse_args(["--addresses", "4", "--seconds", "2", "--operator-after", "1",
                                                      "--pause", "0.05"])) == 0
    doc = json.loads(capsys.readouterr().out)
    f = doc["figures"]
    assert doc["benchmark"] == "console_login" and doc["parameters"]["addresses"] == 4
    assert f["evaluated_failures"] <= f["budget_ceiling"], f
    assert f["codes"].get("429", 0) > 0, f
    assert f["operator_with_device_cookie"] == {"in_after_s": f["operator_with_device_cookie"]["in_after_s"],
                                                "attempts": 1}, f
    assert f["mistyped_5_times"] == {"waited_between_s": 7, "then_told_to_wait_s": 8}, f
    assert set(f["host_check"]) == {"one_address_us", "wildcard_us", "foreign_name_us"}
    assert f["malformed_requests"] == {"sent": 100, "log_records": 1, "tracebacks": 0}, f
