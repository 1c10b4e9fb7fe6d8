"""`simreel filter --verified/--diverged REPORT`: a file that is no replay report (a conversion's report, a
recording's JSON sidecar, not JSON) is one line saying what it is and which report to give, exit 2."""

from __future__ import annotations

import pytest

from simreel.cli.main import main

REPLAY_REPORT = "--verified and --diverged take the report that `simreel replay --report REPORT.json` writes\n"


@pytest.fixture(scope="module")
def converted(record, tmp_path_factory):
    """(recording, the JSON report of its conversion to state observations)."""
    src = record("PickCube-v1", 1, 5)
    folder = tmp_path_factory.mktemp("converted")
    report = folder / "convert_report.json"
    assert main(["convert", str(src), str(folder / "state.h5"), "--obs-mode", "state", "--report", str(report),
                 "-q"]) == 0
    return src, report


def test_a_conversions_report_is_named_as_such(converted, tmp_path, capsys):
    """Regression: it was `not a simreel replay report (KeyError: 'files')`, a Python exception name."""
    src, report = converted
    capsys.readouterr()
    assert main(["filter", str(src), "-o", str(tmp_path / "out.h5"), "--verified", str(report), "-q"]) == 2
    assert capsys.readouterr().err == (f"simreel filter: error: {report}: a conversion's report (`simreel convert "
                                       f"--report`), not a replay report; {REPLAY_REPORT}")
    assert not (tmp_path / "out.h5").exists()


@pytest.mark.parametrize(("text", "what"), [
    ('{"env_info": {}, "episodes": []}', "a recording's JSON sidecar (ManiSkill's trajectory JSON), not a replay report"),
    ('{"files": [], "episodes": [{"index": 0}]}', "a JSON document without a replay report's files and episodes, "
                                                  "not a replay report"),
    ("[1, 2", "it is not JSON (Expecting ',' delimiter at line 1 column 6): not a simreel replay report"),
])
def test_other_json_is_named_for_what_it_is(converted, tmp_path, capsys, text, what):
    src, _ = converted
    report = tmp_path / "other.json"
    report.write_text(text)
    capsys.readouterr()
    assert main(["filter", str(src), "-o", str(tmp_path / "out.h5"), "--diverged", str(report), "-q"]) == 2
    assert capsys.readouterr().err == f"simreel filter: error: {report}: {what}; {REPLAY_REPORT}"
