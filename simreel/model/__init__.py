"""simreel.model: the one episode data model every format, verdict and room goes by.

- `meta`: `RecordingMeta` (everything needed to rebuild the env and judge a replay), `EpisodeMeta`, `ContactChannel`
  and their JSON codecs; `env_config`: `EnvConfig`, the ``gym.make`` arguments a recording keeps
- `fields`: the field table (`episode_fields`): every array of an episode, by flat name, dtype and row count
- `blocks`: `StepBlock`, consecutive rows of those fields; `episode`: `Episode`, one episode's arrays
- `selection`: `EpisodeSelection` (``--episodes 0,3-7``); `state_tree`: nested state dicts and their key paths
- `components`: how a state leaf splits into components, the error between two rows, the tolerances

Pure Python and numpy: nothing here imports a simulator, a file format or a viewer.
"""
