"""simreel.verdicts: what a replay is judged by — the per-leaf comparison and the first divergence (`compare`),
the explanation of a divergence from the data (`divergence`), and the scene history an episode must be replayed
after (`scene_history`). Pure numpy, over the data model; the replay room and the viewers share it."""
