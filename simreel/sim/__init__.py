"""The live simulator, seen from simreel: build an env, describe it, read and restore its state.

- `make`: build an env (`make_env`, `EnvConfig`), with `render_device` (which device renders) and `norender`
  (the state-only compatibility layer); `user_code`: the ``--import`` of user tasks and policies
- `rebuild`: rebuild a recording's env from its metadata and reset it to an episode's scene; `seeds`: the seeds
  ManiSkill takes
- `describe`: the `RecordingMeta` of a live env and the names of its bodies
- `state`: read, restore and layout-check the state dict; `contacts`, `poses`: contact forces and body poses;
  `step_rows`: what turns a block of a recorder's per-step captures into arrays (in its writer process too)

Importing this package imports nothing heavy; mani_skill, sapien and torch load when a function needs them.
"""
