"""ManiSkill's own trajectory files: their layout (`layout`, which simreel's HDF5 recordings share), the JSON
sidecar (`sidecar`, written and read) and a reader (`reader`) that maps them onto simreel's episode model."""
