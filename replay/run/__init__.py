"""The replay run: the engine that rebuilds an env and replays an episode (`engine`, with its options in
`replayer_options`; how it starts an episode, `resets`; its steps, `stepping`; a block's arrays, `blocks`; where
the rows go, `sinks`; what it wraps env calls in, `guards`), the run over recordings (`verify`), its work list
(`worklist`), the workers that replay episodes (`workers`, given a `job`, keeping their readers open in `readers`),
the local process pool and the Ray pool (`pool`, `ray_pool`), the replay it writes (`output`), the scene history an
episode is replayed after (`history`; how a worker replays it, `history_replay`) and the scene fingerprint check at
each reset (`fingerprint`)."""
