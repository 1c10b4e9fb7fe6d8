"""`simreel.formats` itself: what it answers for every format (output checks, removal, pose default, row 0)."""

from __future__ import annotations

import pytest

from simreel.errors import UsageError
from simreel.formats import check_report_writable, check_writable, records_poses_by_default


@pytest.mark.parametrize(
    ("name", "poses"), [("a.mcap", True), ("a.MCAP", True), ("a.h5", False), ("dir/a.hdf5", False)]
)
def test_records_poses_by_default_only_for_mcap(name, poses):
    assert records_poses_by_default(name) is poses


def test_records_poses_by_default_refuses_an_unknown_suffix():
    with pytest.raises(UsageError, match=r"a\.txt: unknown recording suffix '\.txt'"):
        records_poses_by_default("a.txt")


@pytest.mark.parametrize("command", [["recover", "{d}"], ["merge", "{rec}", "-o", "{d}"], ["convert", "{rec}", "{d}"]])
def test_a_folder_named_as_a_recording_is_called_a_folder(record, tmp_path, capsys, command):
    """Regression: a folder without a suffix was "d: unknown recording suffix ''", as if a file's name were wrong."""
    from simreel.cli.main import main

    folder = tmp_path / "d"
    folder.mkdir()
    args = [a.format(d=folder, rec=record("PickCube-v1", 1, 3)) for a in command]
    assert main(args) == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        f"error: {folder} is a folder, not a recording; name a .h5 (HDF5) or .mcap (MCAP) file")
    assert list(folder.iterdir()) == []


@pytest.mark.parametrize(
    ("target", "make", "overwrite", "message"),
    [
        ("out.mcap", None, False, None),
        ("out.h5", None, False, None),
        ("out.txt", None, False, "out.txt: unknown recording suffix '.txt'"),
        ("missing/out.mcap", None, True, "cannot write {tmp}/missing/out.mcap: folder {tmp}/missing does not exist"),
        ("out.mcap", "out.mcap", False, "{tmp}/out.mcap already exists; pass --overwrite to replace it"),
        ("out.mcap", "out.mcap", True, None),
        ("out.h5", "out.json", False,
         "{tmp}/out.json already exists and writing out.h5 would replace it; pass --overwrite to replace it"),
        ("out.h5", "out.json", True, None),
    ],
)
def test_check_writable_raises_what_the_writer_would_and_touches_nothing(tmp_path, target, make, overwrite, message):
    if make:
        (tmp_path / make).write_text("mine")
    before = sorted(tmp_path.iterdir())
    if message is None:
        check_writable(tmp_path / target, overwrite=overwrite)
    else:
        with pytest.raises(UsageError) as err:
            check_writable(tmp_path / target, overwrite=overwrite)
        assert message.format(tmp=tmp_path) in str(err.value)
    assert sorted(tmp_path.iterdir()) == before
    if make:
        assert (tmp_path / make).read_text() == "mine"


def test_a_sidecar_another_hdf5_file_shares_is_never_replaced(tmp_path, record):
    """Regression: `-o x.hdf5 --overwrite` replaced `x.json`, the sidecar of `x.h5` (ManiSkill's tools read it for
    `x.h5`), though `x.hdf5` did not even exist; refused now, by the command's early check and by the writer."""
    import shutil

    from simreel.formats import open_reader, open_writer

    src = record("PickCube-v1", 1, 3)
    shutil.copy(src, tmp_path / "x.h5")
    shutil.copy(src.with_suffix(".json"), tmp_path / "x.json")
    sidecar = (tmp_path / "x.json").read_bytes()
    before = sorted(tmp_path.iterdir())
    with open_reader(tmp_path / "x.h5") as r:
        meta = r.meta
    said = (f"{tmp_path}/x.json is the JSON sidecar of {tmp_path}/x.h5, which ManiSkill's tools read with it; writing "
            f"{tmp_path}/x.hdf5 would replace it: name the output otherwise")
    for attempt in (lambda: check_writable(tmp_path / "x.hdf5", overwrite=True),
                    lambda: open_writer(tmp_path / "x.hdf5", meta, overwrite=True)):
        with pytest.raises(UsageError) as err:
            attempt()
        assert str(err.value) == said
    assert sorted(tmp_path.iterdir()) == before and (tmp_path / "x.json").read_bytes() == sidecar
    check_writable(tmp_path / "x.h5", overwrite=True)  # the sidecar's own recording may replace it


@pytest.mark.parametrize(
    ("files", "owner"),
    [
        (["x.h5", "x.json"], "x.h5"),
        (["x.hdf5", "x.json"], "x.hdf5"),
        (["x.H5", "x.json"], "x.H5"),
        (["x.json"], None),  # a report being replaced: no recording reads it
        (["x.h5"], None),  # no sidecar there to lose (simreel's .h5 holds its own metadata)
        (["x.b.h5", "x.json"], None),  # x.b.h5's sidecar is x.b.json
        (["x.mcap", "x.json"], None),
    ],
)
def test_a_report_never_replaces_a_recordings_sidecar(tmp_path, files, owner):
    """Regression: `--report x.json --overwrite` (replay, convert) and `audit --json x.json --overwrite` replaced
    the JSON sidecar of `x.h5`, which ManiSkill's tools read with it; the recordings' own rule refuses it now,
    --overwrite or not, and touches nothing."""
    for name in files:
        (tmp_path / name).write_text(name)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    if owner is None:
        assert check_report_writable(tmp_path / "x.json", overwrite=True, option="--report") == tmp_path / "x.json"
    else:
        with pytest.raises(UsageError) as err:
            check_report_writable(tmp_path / "x.json", overwrite=True, option="--report")
        assert str(err.value) == (f"{tmp_path}/x.json is the JSON sidecar of {tmp_path}/{owner}, which ManiSkill's "
                                  f"tools read with it; writing --report {tmp_path}/x.json would replace it: name "
                                  "the output otherwise")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_a_file_simreel_writes_beside_recordings_is_named_when_given_as_one(tmp_path, capsys):
    """Before: a replay report, a ManiSkill JSON sidecar or a Rerun session given where a recording goes (`view
    --compare report.json`, `inspect run.json`) was only "neither an HDF5 nor an MCAP file"; now the refusal says
    what the file is and what to give: the recordings the report names, the .h5 beside the sidecar, `rerun`."""
    from support.maniskill_files import record_maniskill

    from simreel.cli.main import main
    from simreel.errors import RecordingFileError
    from simreel.formats import open_reader

    recording, report, replayed = tmp_path / "run.h5", tmp_path / "report.json", tmp_path / "replayed.h5"
    assert main(["record", "PickCube-v1", "-o", str(recording), "-n", "1", "--max-steps", "5", "--render-backend",
                 "none", "-q"]) == 0
    assert main(["replay", str(recording), "--report", str(report), "-o", str(replayed), "-q"]) == 0
    saved = tmp_path / "x.rrd"
    assert main(["view", str(recording), "--save", str(saved), "--geometry", "collision"]) == 0
    sidecar = record_maniskill(tmp_path / "ms", "PickCube-v1", episodes=1, steps=3).with_suffix(".json")
    other = tmp_path / "other.json"
    other.write_text('{"episodes": []}')
    expected = {
        report: f": a replay report (`simreel replay --report`); give a recording: the one it judged is {recording}, "
                f"and the replay it wrote: {replayed}",
        sidecar: f": the JSON sidecar of a ManiSkill trajectory; give the .h5 beside it ({sidecar.with_suffix('.h5')})",
        saved: f": a Rerun session (`simreel view --save` writes them); open it with `rerun {saved}`",
        other: "",
    }
    for path, what in expected.items():
        with pytest.raises(RecordingFileError) as refused:
            open_reader(path)
        assert str(refused.value) == f"{path}: neither an HDF5 nor an MCAP file{what}"
    capsys.readouterr()
    assert main(["view", str(recording), "--compare", str(report), "--save", str(tmp_path / "y.rrd")]) == 2
    assert capsys.readouterr().err.strip() == f"simreel view: error: {report}: neither an HDF5 nor an MCAP file" \
                                              f"{expected[report]}"


CHUNK = "the bytes of messages per chunk, an int >= 1 (default 1 MiB)"


@pytest.mark.parametrize(
    ("name", "options", "message"),
    [
        # was: accepted as yes, and the file there was replaced
        ("out.h5", {"overwrite": "no"}, "overwrite='no': give True or False"),
        ("out.mcap", {"overwrite": "no"}, "overwrite='no': give True or False"),
        # was: TypeError McapOptions.__init__() got an unexpected keyword argument 'level'
        ("out.mcap", {"level": 3}, "writer_options level: not an option of the MCAP writer, which takes compression, "
                                   "chunk_size, fsync"),
        ("out.h5", {"level": 3}, "writer_options level: not an option of the HDF5 writer, which takes compression"),
        # was: TypeError '>' not supported between instances of 'int' and 'str', inside mcap's writer
        ("out.mcap", {"chunk_size": "1M"}, f"chunk_size='1M': give {CHUNK}"),
        ("out.mcap", {"chunk_size": 0}, f"chunk_size=0: give {CHUNK}"),  # was: one chunk per message
        ("out.mcap", {"chunk_size": True}, f"chunk_size=True: give {CHUNK}"),  # was: taken as 1
        ("out.mcap", {"fsync": "no"}, "fsync='no': give True or False"),  # was: accepted as yes
        ("out.h5", {"compression": "zstd"}, "unknown HDF5 compression 'zstd'; use one of gzip, lzf, None"),  # as before
    ],
    ids=["h5-overwrite-str", "mcap-overwrite-str", "mcap-unknown", "h5-unknown", "chunk_size-str", "chunk_size-0",
         "chunk_size-bool", "fsync-str", "h5-compression"],
)
def test_open_writer_refuses_an_option_it_cannot_take_and_touches_nothing(record, tmp_path, name, options, message):
    from simreel.formats import open_reader, open_writer

    with open_reader(record("PickCube-v1", 2, 5)) as reader:
        meta = reader.meta
    (tmp_path / name).write_text("an older file, to be kept")
    with pytest.raises(UsageError) as refused:
        open_writer(tmp_path / name, meta, **options)
    assert str(refused.value) == message
    assert [p.name for p in tmp_path.iterdir()] == [name] and (tmp_path / name).read_text() == "an older file, to be kept"
