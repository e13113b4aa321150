"""What the job form calls each option, and job refusals reworded for the page: with the jobs'
real option declarations (the calibrate job's refusal of no known points names flags)."""
from __future__ import annotations

from coordinator.console.page_wording import PAGE_HINTS, for_the_page, helps_for_the_page, job_for_the_page
from coordinator.jobs.options import derive_label, derive_unit, form_fields
from coordinator.jobs.registry import resolve

CLI_REFUSAL = ("the table -> camera mapping needs known points: set table_points (a points file, or [calibration] "
               "table_points = [[x_mm, y_mm, u_px, v_px], ...] in rig.toml) or a charuco board (e.g. a first run "
               "with --charuco board.json --table-only, then remove the board)")


def test_labels_are_derived_from_names_unless_declared():
    assert derive_label("keep_going") == "Keep going"
    assert derive_label("settle_s") == "Settle (s)" and derive_unit("settle_s") == "s"
    assert derive_label("max_iter") == "Maximum iterations"
    assert derive_label("srgb") == "sRGB" and derive_label("lut_entries") == "LUT entries"
    assert derive_unit("radius") == "" and derive_unit("s") == ""
    fields = {f["name"]: f for f in form_fields(resolve("calibrate").options)}
    assert fields["table_mm"]["label"] == "Table size (mm)" and fields["table_mm"]["unit"] == "mm"   # declared
    assert fields["keep_going"]["label"] == "Keep going" and fields["keep_going"]["flag"] == "--keep-going"
    assert fields["intrinsics"]["flag"] == ""          # no command-line flag
    for kind in ("calibrate", "compensate_video"):     # every option has a label and help
        for f in form_fields(resolve(kind).options):
            assert f["label"] and f["label"] != f["name"] and f["help"], (kind, f["name"])


def test_a_refusal_naming_flags_speaks_of_the_form():
    page = for_the_page("calibrate", CLI_REFUSAL)
    assert "--" not in page and "table_points (" not in page
    assert "set “Table points” (a points file" in page
    assert "[calibration] table_points = [[" in page            # rig.toml's syntax stays as written
    assert "with “ChArUco board” set to board.json and “Table only” ticked, then remove the board" in page
    assert page.endswith(PAGE_HINTS[("calibrate", "needs known points")])
    assert for_the_page("calibrate", "stop with --no-keep-going") == "stop with “Keep going” unticked"
    # a flag that is no option of the job, and other jobs' words, stay
    assert for_the_page("calibrate", "pass --camera to `shadowless calibrate`") == \
        "pass --camera to `shadowless calibrate`"
    assert for_the_page("compensate", "or --show it") == "or “Show the result” ticked it"
    assert for_the_page(None, "x --charuco b") == "x --charuco b" and for_the_page("calibrate", None) is None
    job = {"kind": "calibrate", "state": "failed", "error": CLI_REFUSAL, "message": "", "log": []}
    assert job_for_the_page(job)["error"] == page and job["error"] == CLI_REFUSAL


def test_the_forms_help_texts_name_fields_not_flags():
    fields = {f["name"]: f for f in helps_for_the_page(form_fields(resolve("calibrate").options))}
    assert "(“Use table” unticked: the object only)" in fields["use_table"]["help"]
    assert "--no-table" not in fields["use_table"]["help"]
    video = {f["name"]: f for f in helps_for_the_page(form_fields(resolve("compensate_video").options))}
    # a flag followed by a plain word takes no value: "--first-iterations at its first frame"
    assert "(“First iterations” at its first frame)" in video["segment_frames"]["help"]
