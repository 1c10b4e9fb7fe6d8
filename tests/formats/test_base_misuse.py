"""What `open_writer`'s writers do with what a careless Python caller hands them, in both formats: values a field's
dtype cannot hold, sinks used out of order, reset rows that are not one row, metadata a reader would refuse. Each is
one clear error before anything reaches the file, never a file that holds other values or other episodes than given,
and the writer goes on with the next episode."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from simreel.errors import EpisodeLayoutError, UsageError
from simreel.formats import open_reader, open_writer
from simreel.model.blocks import StepBlock
from simreel.model.episode import Episode
from simreel.model.lineage import SceneChain
from simreel.model.meta import EpisodeMeta

SUFFIXES = [".h5", ".mcap"]


@pytest.fixture(scope="module")
def source(record):
    """A real PickCube-v1 recording's metadata and its first episode (20 steps)."""
    with open_reader(record("PickCube-v1", 2, 20)) as reader:
        return reader.meta, reader.read_episode(0)


def _changed(episode: Episode, **arrays: np.ndarray) -> Episode:
    """`episode` with the flat fields `arrays` (``info/elapsed_steps`` as ``info__elapsed_steps``) replaced."""
    fields = dict(episode.fields())
    fields.update({name.replace("__", "/"): a for name, a in arrays.items()})
    return Episode.from_fields(episode.meta, fields)


def _read_all(path) -> dict[int, Episode]:
    with open_reader(path) as reader:
        return {m.index: reader.read_episode(m.index) for m in reader.episodes}


def _assert_same(read: Episode, written: Episode) -> None:
    for name, a in written.fields().items():
        np.testing.assert_array_equal(read.fields()[name], a, err_msg=name)


# ---------------------------------------------------------------------------------------------------- values
@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize(
    "case",
    [
        ("actions", lambda a: a.astype(np.float64) * 1e300,
         r"actions holds -8.2\d*e\+299 \(float64\), which float32 cannot hold \(it would be stored as -inf\)"),
        ("info/elapsed_steps", lambda a: np.full(a.shape, 2**40, np.int64),
         r"info/elapsed_steps holds 1099511627776 \(int64\), which int32 cannot hold \(it would be stored as 0\)"),
        ("info/elapsed_steps", lambda a: np.full(a.shape, 2.7),
         r"info/elapsed_steps holds 2.7 \(float64\), which int32 cannot hold \(it would be stored as 2\)"),
        ("terminated", lambda a: np.full(a.shape, 2, np.uint8),
         r"terminated holds 2 \(uint8\), which bool cannot hold \(it would be stored as True\)"),
        ("terminated", lambda a: np.full(a.shape, 0.5), r"terminated holds 0.5 \(float64\), which bool cannot hold \(it would be stored as True\)"),
        ("terminated", lambda a: np.full(a.shape, np.nan), r"terminated holds nan \(float64\), which bool cannot hold \(it would be stored as True\)"),
        ("actions", lambda a: a + 1j, r"actions is complex64, not numbers of the layout's float32"),
        ("actions", lambda a: np.full(a.shape, "1.5"), r"actions is <U3, not numbers of the layout's float32"),
        ("actions", lambda a: a.astype(object), r"actions is object, not numbers of the layout's float32"),
    ],
    ids=["overflow", "int-wraps", "float-to-int", "uint8-to-bool", "half-to-bool", "nan-to-bool", "complex", "text",
         "object"],
)
def test_a_value_the_fields_dtype_cannot_hold_is_refused_not_stored_changed(tmp_path, source, suffix, case):
    (name, make, message), (meta, episode) = case, source
    fields = episode.fields()
    bad = Episode.from_fields(episode.meta, {**fields, name: make(fields[name])})
    path = tmp_path / f"out{suffix}"
    with open_writer(path, meta) as writer:
        with pytest.raises(EpisodeLayoutError, match=f"^episode 0: {message}; give values of that dtype"):
            writer.write_episode(bad)
        writer.write_episode(dataclasses.replace(episode, meta=dataclasses.replace(episode.meta, index=1)))
    assert list(_read_all(path)) == [1]  # the refused episode left nothing; the writer went on


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_values_another_dtype_holds_exactly_or_rounded_are_stored_as_the_layouts_dtype(tmp_path, source, suffix):
    meta, episode = source
    given = _changed(
        episode,
        actions=episode.actions.astype(np.float64) + 0.1,  # rounded to float32, as a float32 field stores any float
        rewards=np.arange(episode.length, dtype=np.int64),
        terminated=episode.terminated.astype(np.uint8),
        truncated=episode.truncated.astype(np.float64),
        info__elapsed_steps=np.asarray(episode.info["elapsed_steps"], np.int64),
        contact_forces=np.asfortranarray(episode.contact_forces.astype(">f4")),
    )
    path = tmp_path / f"out{suffix}"
    with open_writer(path, meta) as writer:
        writer.write_episode(given)
    read = _read_all(path)[0]
    for name, a in given.fields().items():
        assert read.fields()[name].dtype == episode.fields()[name].dtype, name
        np.testing.assert_array_equal(read.fields()[name], a.astype(episode.fields()[name].dtype), err_msg=name)


# ---------------------------------------------------------------------------------------------------- sinks
def _other(episode: Episode, index: int) -> Episode:
    return dataclasses.replace(episode, meta=dataclasses.replace(episode.meta, index=index))


def _misuse_commit_other_index(writer, episode):
    sink = writer.begin_episode(episode.meta, episode.reset_block())
    sink.append(episode.steps_block())
    sink.commit(dataclasses.replace(episode.meta, index=5))


def _misuse_commit_twice(writer, episode):
    sink = writer.begin_episode(episode.meta, episode.reset_block())
    sink.append(episode.steps_block())
    sink.commit(episode.meta)
    sink.commit(episode.meta)


def _misuse_append_after_commit(writer, episode):
    sink = writer.begin_episode(episode.meta, episode.reset_block())
    sink.append(episode.steps_block())
    sink.commit(episode.meta)
    sink.append(episode.steps_block())


def _misuse_commit_after_discard(writer, episode):
    sink = writer.begin_episode(episode.meta, episode.reset_block())
    sink.append(episode.steps_block())
    sink.discard()
    sink.commit(episode.meta)


def _misuse_wrong_length(writer, episode):
    sink = writer.begin_episode(episode.meta, episode.reset_block())
    sink.append(episode.steps_block())
    sink.commit(dataclasses.replace(episode.meta, length=99))


def _misuse_default_length(writer, episode):
    """An episode a user built with `EpisodeMeta(index=0)`: length 0, the default, with 20 steps."""
    writer.write_episode(dataclasses.replace(episode, meta=EpisodeMeta(index=0)))


def _misuse_two_row_reset(writer, episode):
    two = StepBlock.of({n: a[:2] for n, a in episode.fields().items() if n.startswith("env_states/")})
    writer.begin_episode(episode.meta, two)


def _misuse_empty_reset(writer, episode):
    none = StepBlock.of({n: a[:0] for n, a in episode.fields().items() if n.startswith("env_states/")})
    writer.begin_episode(episode.meta, none)


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize(
    "case",
    [
        (_misuse_commit_other_index, UsageError, "commit of episode 5 on the sink of episode 0", []),
        (_misuse_commit_twice, UsageError, "episode 0 was already committed or discarded", [0]),
        (_misuse_append_after_commit, UsageError, "episode 0 was already committed or discarded", [0]),
        (_misuse_commit_after_discard, UsageError, "episode 0 was already committed or discarded", []),
        (_misuse_wrong_length, UsageError,
         r"episode 0: committed with length 99, but 20 step\(s\) were appended; give EpisodeMeta\(length=20\)", []),
        (_misuse_default_length, UsageError,
         r"episode 0: committed with length 0, but 20 step\(s\) were appended; give EpisodeMeta\(length=20\)", []),
        (_misuse_two_row_reset, EpisodeLayoutError,
         r"episode 0: the reset block has 2 rows, expected 1 \(the state right after the reset\)", []),
        (_misuse_empty_reset, EpisodeLayoutError,
         r"episode 0: the reset block has 0 rows, expected 1 \(the state right after the reset\)", []),
    ],
    ids=["commit-other-index", "commit-twice", "append-after-commit", "commit-after-discard", "wrong-length",
         "default-length", "two-row-reset", "empty-reset"],
)
def test_a_sink_used_out_of_order_is_one_error_and_the_file_keeps_exactly_what_was_committed(tmp_path, source, suffix,
                                                                                            case):
    (misuse, error, message, kept), (meta, episode) = case, source
    path = tmp_path / f"out{suffix}"
    with open_writer(path, meta) as writer:
        with pytest.raises(error, match=f"^{message}"):
            misuse(writer, episode)
        writer.write_episode(_other(episode, 1))  # the writer goes on
    read = _read_all(path)
    assert sorted(read) == [*kept, 1]
    for index in read:
        _assert_same(read[index], _other(episode, index))
        assert read[index].meta.length == episode.length


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("end", ["close", "abort"])
def test_a_sink_takes_nothing_once_its_writer_is_closed_or_aborted(tmp_path, source, suffix, end):
    meta, episode = source
    path = tmp_path / f"out{suffix}"
    writer = open_writer(path, meta)
    writer.write_episode(episode)
    sink = writer.begin_episode(_other(episode, 1).meta, episode.reset_block())
    getattr(writer, end)()
    with pytest.raises(UsageError, match=f"^{path} is closed$"):
        sink.append(episode.steps_block())
    with pytest.raises(UsageError, match=f"^{path} is closed$"):
        sink.commit(_other(episode, 1).meta)
    sink.discard()  # cleaning up after a closed writer is no error
    if end == "close":
        assert list(_read_all(path)) == [0]
    else:
        assert not path.exists()


# ---------------------------------------------------------------------------------------------------- metadata
@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"env_id": 5}, "recording metadata: env_id is 5, expected str"),
        ({"num_envs": 0}, "recording metadata: num_envs is 0, expected >= 1"),
        ({"control_freq": "20"}, "recording metadata: control_freq is '20', expected float | None"),
        ({"control_freq": float("nan")}, "recording metadata: control_freq is nan, expected a number > 0 or None"),
        ({"sim_freq": -100.0}, "recording metadata: sim_freq is -100.0, expected a number > 0 or None"),
        ({"env_kwargs": {(1, 2): "b"}}, "recording metadata does not convert to JSON: keys must be str"),
    ],
    ids=["env-id", "num-envs", "freq-text", "freq-nan", "freq-negative", "tuple-key"],
)
def test_recording_metadata_a_reader_would_refuse_is_refused_before_the_file_is_made(tmp_path, source, suffix,
                                                                                     changes, message):
    meta, _ = source
    path = tmp_path / f"out{suffix}"
    with pytest.raises(UsageError, match=f"^{path}: {message}"):
        open_writer(path, dataclasses.replace(meta, **changes))
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"index": 3.0}, "episode metadata: index is 3.0, expected int"),
        ({"index": "3"}, "episode metadata: index is '3', expected int"),
        ({"index": True}, "episode metadata: index is True, expected int"),
        ({"index": -1}, "episode metadata: index is -1, expected >= 0"),
        ({"env_idx": -2}, "episode metadata: env_idx is -2, expected >= 0"),
        ({"chain": SceneChain("a", 0)}, "episode metadata: chain is"),
        ({"reset_options": {(1, 2): "b"}}, "episode metadata does not convert to JSON: keys must be str"),
    ],
    ids=["float-index", "text-index", "bool-index", "negative-index", "negative-env", "chain", "tuple-key"],
)
def test_episode_metadata_a_reader_would_refuse_is_refused_before_the_episode_begins(tmp_path, source, suffix,
                                                                                    changes, message):
    meta, episode = source
    path = tmp_path / f"out{suffix}"
    with open_writer(path, meta) as writer:
        with pytest.raises(UsageError, match=f"^{path}: {message}"):
            writer.write_episode(dataclasses.replace(episode, meta=dataclasses.replace(episode.meta, **changes)))
        writer.write_episode(_other(episode, 1))
    assert list(_read_all(path)) == [1]


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_numpy_numbers_and_text_that_is_no_utf8_in_metadata_are_written_as_given(tmp_path, source, suffix):
    meta, episode = source
    meta = dataclasses.replace(meta, command="simreel record -o caf\udce9.mcap", control_freq=np.float64(20.0))
    given = dataclasses.replace(episode.meta, index=np.int64(3), seed=np.int32(5), length=np.int64(episode.length),
                                notes=["bad \udcff text"])
    path = tmp_path / f"out{suffix}"
    with open_writer(path, meta) as writer:
        writer.write_episode(dataclasses.replace(episode, meta=given))
    with open_reader(path) as reader:
        assert reader.meta.command == meta.command
        (read,) = reader.episodes
        assert (read.index, read.seed, read.length, read.notes) == (3, 5, episode.length, given.notes)
        assert type(read.index) is int


# ---------------------------------------------------------------------------------------------------- readers
@pytest.mark.parametrize("suffix", SUFFIXES)
def test_a_closed_reader_and_the_episodes_it_opened_say_so_instead_of_calling_the_file_corrupt(tmp_path, source,
                                                                                             suffix):
    meta, episode = source
    path = tmp_path / f"out{suffix}"
    with open_writer(path, meta) as writer:
        writer.write_episode(episode)
    reader = open_reader(path)
    rows = reader.open_episode(0)
    reader.close()
    closed = f"^{path}: this reader is closed; open_reader the file again$"
    for read in (lambda: reader.read_episode(0), lambda: reader.open_episode(0), rows.reset,
                 lambda: list(rows.blocks(4)), lambda: rows.steps(0, 4)):
        with pytest.raises(UsageError, match=closed):
            read()


@pytest.mark.parametrize(("suffix", "chunk_size"), [(".h5", None), (".mcap", None), (".mcap", 1)],
                         ids=["h5", "mcap-one-chunk", "mcap-chunk-per-message"])
def test_reading_on_after_close_is_refused_as_closed_not_taken_for_a_corrupt_chunk(tmp_path, source, suffix,
                                                                                   chunk_size):
    """An episode's blocks, and its steps read in order, begun before `close()` and read on after it. Before, MCAP
    read on from rows it held in memory (one chunk) or called the next chunk of a sound file corrupt ("seek of closed
    file"); HDF5 already refused."""
    meta, episode = source
    path = tmp_path / f"out{suffix}"
    options = {"chunk_size": chunk_size} if chunk_size else {}
    with open_writer(path, meta, **options) as writer:  # five messages of 4 steps: with chunk_size=1, five chunks
        sink = writer.begin_episode(episode.meta, episode.reset_block())
        steps = episode.steps_block()
        for start in range(0, episode.length, 4):
            sink.append(StepBlock.of({name: a[start:start + 4] for name, a in steps.arrays.items()}))
        sink.commit(episode.meta)
    closed = f"^{path}: this reader is closed; open_reader the file again$"
    reader = open_reader(path)
    rows = reader.open_episode(0)
    blocks = rows.blocks(4)  # the next block: in memory (one chunk), or in the next chunk
    assert next(blocks)[0] == 0
    assert rows.steps(0, 2).rows == 2
    reader.close()
    with pytest.raises(UsageError, match=closed):
        next(blocks)
    with pytest.raises(UsageError, match=closed):
        rows.steps(2, 4)


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("index", ["0", 0.0, False, None])
def test_an_episode_index_that_is_no_int_is_one_usage_error(tmp_path, source, suffix, index):
    """Before: read_episode("0") said "no episode 0 (episodes: 0)" of a file that has it, and 0.0 and False were
    taken for episode 0."""
    meta, episode = source
    path = tmp_path / f"out{suffix}"
    with open_writer(path, meta) as writer:
        writer.write_episode(episode)
    with open_reader(path) as reader:
        with pytest.raises(UsageError, match=re.escape(f"{path}: episode index {index!r}: give an int")):
            reader.read_episode(index)
        assert reader.read_episode(np.int64(0)).length == episode.length


@pytest.mark.parametrize("suffix", SUFFIXES)
@pytest.mark.parametrize("name", ["rewards", "actions"])
def test_an_episode_field_that_is_no_array_is_one_layout_error_and_nothing_is_written(tmp_path, source, suffix, name):
    """Before: `write_episode` of an Episode holding a Python list raised AttributeError ('list' object has no
    attribute 'shape') from inside."""
    meta, episode = source
    path = tmp_path / f"out{suffix}"
    bad = dataclasses.replace(episode, **{name: getattr(episode, name).tolist()})
    with open_writer(path, meta) as writer:
        with pytest.raises(EpisodeLayoutError, match=f"^episode 0: {name} is a list, not a numpy array; give each "
                                                      "field as an array of the layout's dtype$"):
            writer.write_episode(bad)
        writer.write_episode(episode)
    assert list(_read_all(path)) == [0]
