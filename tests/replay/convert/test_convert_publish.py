"""A conversion's output is read back and checked before it is published (`simreel.replay.convert.convert`): one whose
check fails is never moved to its name, an old file it was to replace stays as it was, and no scratch file stays.
The staged file is changed for real, through the public `progress` hook, after its last episode was written and
before it is read back (another handle writing into it, as a faulty writer or disk would)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from support.maniskill_files import record_maniskill

from simreel.cli.main import main
from simreel.errors import OutputCheckError
from simreel.io.lock import being_written
from simreel.replay.convert.convert import convert_recording
from simreel.replay.convert.report import ConversionReport
from simreel.replay.convert.run import ConversionRun
from simreel.replay.run.output import scratch_folder

STEPS = 8


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    return record_maniskill(tmp_path_factory.mktemp("demos"), "PickCube-v1", name="pick", episodes=2, steps=STEPS,
                            path="smooth", path_seed=102)


def _written_now(out: Path) -> Path:
    """The file a writer is writing the output `out` to now: staged in the run's scratch folder, staged beside an old
    `out` by the HDF5 writer itself, or `out` (the first of them that exists and a writer holds)."""
    candidates = (scratch_folder(out) / f"output{out.suffix}", out.with_name(f"{out.name}.partial") / out.name, out)
    return next(p for p in candidates if p.is_file() and being_written(p))


def _corrupting(out: Path, index: int = 1):
    """A `progress` callback that changes one action of episode `index` in the output being written, once written."""
    import h5py

    def corrupt(episode) -> None:
        if episode.index == index:
            with h5py.File(_written_now(out), "r+", locking=False) as f:  # the writer's own open file, shared by HDF5
                actions = f[f"traj_{index}/actions"]
                actions[3] = actions[3] + 1.0

    return corrupt


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_an_output_that_fails_its_read_back_is_not_published_and_the_old_one_stays(demos, tmp_path):
    out = tmp_path / "out.h5"
    for src, dst in ((demos, out), (demos.with_suffix(".json"), out.with_suffix(".json"))):
        shutil.copyfile(src, dst)  # an old output, replaced only by a checked one
    before = {p: p.read_bytes() for p in tmp_path.iterdir()}
    reports = []
    corrupt = _corrupting(out)

    def progress(episode) -> None:
        reports.append(episode)
        corrupt(episode)

    with pytest.raises(OutputCheckError, match=r"out.h5: episodes \[1\] do not read back as they were written; "
                                               r"nothing was written to .*out.h5$"):
        convert_recording(demos, out, control_mode="pd_joint_delta_pos", overwrite=True, progress=progress)
    assert {p: p.read_bytes() for p in tmp_path.iterdir()} == before  # no scratch folder, no staged file left
    # a summary never counts as verified an episode whose written data failed the read-back
    report = ConversionReport(path=str(demos), output=str(out), env_id="PickCube-v1", conversion={"checked": "..."},
                              tolerances={}, episodes=reports, written=[0, 1], written_mismatch=[1])
    assert all(e.ok for e in reports)
    assert "1 of 2 episode(s) verified" in report.summary() and not report.ok


def test_the_command_exits_3_in_one_line_and_writes_nothing(demos, tmp_path, capsys, monkeypatch):
    """As `simreel merge`: a file that does not read back as written is simreel's bug (exit 3), removed. The
    command line has no progress hook of its own: `execute` is wrapped to pass the corrupting one along."""
    out, report = tmp_path / "out.h5", tmp_path / "report.json"
    execute = ConversionRun.execute

    def with_corruption(self, progress=None):
        corrupt = _corrupting(out)
        return execute(self, lambda episode: (progress and progress(episode), corrupt(episode)))

    monkeypatch.setattr(ConversionRun, "execute", with_corruption)
    status = main(["convert", str(demos), str(out), "--control-mode", "pd_ee_delta_pose", "-q", "--report",
                   str(report)])
    captured = capsys.readouterr()
    assert status == 3 and "verified" not in captured.out
    assert captured.err.startswith(f"simreel convert: internal error: OutputCheckError: {out}: episodes [1] do not "
                                   f"read back as they were written; nothing was written to {out} (")
    assert len(captured.err.splitlines()) == 1
    assert _files(tmp_path) == []
