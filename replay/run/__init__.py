"""The replay run: the engine that rebuilds an env and replays an episode (`engine`), the run over recordings
(`verify`), its work list, local worker processes and Ray pool (`worklist`, `workers`, `ray_pool`), the replay it
writes (`output`), the scene history an episode is replayed after (`history`) and the scene
fingerprint check at each reset (`fingerprint`)."""
