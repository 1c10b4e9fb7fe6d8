"""MCAP recordings: exact data for simreel, and channels Foxglove and Rerun show without simreel.

Channels (one schema each)::

    /simreel/reset   simreel.ResetRow    (simreel-fields)  row 0 of state/obs/poses, one message per episode
    /simreel/steps   simreel.StepBlock   (simreel-fields)  every per-step array, one message per block of steps
    /tf              foxglove.FrameTransforms (protobuf)   world pose of every body, one message per row
    /scene           foxglove.SceneUpdate (protobuf)       every body's shapes on its /tf frame, once per scene
    /robot_description  std_msgs/msg/String (ros2msg/cdr)  a URDF of the same bodies (Rerun draws it), once per scene
    /plots           simreel.StepScalars (jsonschema/json) reward, flags, info scalars, action per step
    /log             foxglove.Log        (protobuf)        episode begins / is committed / is discarded

The data channels hold the arrays bit-exactly (see `simreel.formats.mcap.blocks`); the viewable ones
are derived from them. `/tf` shows `Episode.body_poses` (every actor and articulation link, parent frame
`world`, child frame = body name) when the recording has them (`RecordingMeta.pose_bodies`, the default
for `.mcap`); otherwise it shows what the state dict holds: every actor in it and each articulation's root
link. With `num_envs > 1` child frames are `env<i>/<body>` (sub-scenes share the origin).

Metadata records: `simreel` (format version, `RecordingMeta` JSON, field tables, channel ids, time base),
then per episode i `simreel.episode_begin.<i>`, and `simreel.episode.<i>` (its `EpisodeMeta`, time span,
steps) once it is committed, or `simreel.episode_discard.<i>` (one name per record: Rerun merges records
of the same name).

Time: `log_time = episode start + row × step_ns`, with `step_ns = 1e9 / control_freq` (the env's control
period; 1 s if unknown) and row 0 the state after reset; the first episode starts at the recording's `created_utc`
(`time_origin_ns` in the `simreel` record; 0 in files written before, which viewers show in 1970). The episodes of one parallel env follow each
other on the time axis (the next starts one period after the last row of the previous), so Foxglove's
and Rerun's timelines play the whole recording; each message's `sequence` is its row (step) index, and
every `/plots` message names its episode. `McapReader.read_episode(i)` reads only the chunks in
episode i's span.

Crash safety: `commit` closes the current chunk, writes the `simreel.model` metadata record after it
and flushes to the OS, so a `kill -9` after `commit` returns loses nothing of that episode (`fsync=True`
also survives a power cut). An episode exists for simreel only once its record is in the file: a
discarded or never-committed episode's messages stay in the append-only file (viewers show them; `/log`
says so) but the reader skips them. A killed recording has no summary or footer; `McapReader` refuses it
with one line that points to `simreel recover`, which reads it front to back (`McapReader(path,
recover=True)`), rewrites the committed episodes into a complete file and reports what was lost. The
writer holds an advisory lock on the file, so a file still being written is not taken for a killed one.

The scene (`McapWriter.write_scene`, from a recorder: `simreel.formats.mcap.scene`) is written as the next episode
of its sub-scene begins, and only when it differs from the one written before.

Modules: `writer` writes (`channels` puts each message on its channel); `reader` reads; `blocks` owns the
bytes of the data channels, `foxglove` the Foxglove messages, `scene` the scene's messages, `wire` the protobuf wire
format both write, `records` the metadata records and names both sides share, `layout` a Foxglove layout for the
files.
"""


from simreel.formats.mcap.reader import McapReader
from simreel.formats.mcap.records import COMPRESSIONS, TOPICS, step_ns_of
from simreel.formats.mcap.writer import McapWriter

__all__ = ["McapWriter", "McapReader", "COMPRESSIONS", "TOPICS", "step_ns_of"]
