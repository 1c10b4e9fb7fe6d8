"""simreel.datasets: operations on whole recordings, above the formats — copy, convert between formats and recover
(`copy`), merge and filter (`dataset`), the digests a copy is checked by (`digests`), what made a recording in words
(`provenance`), the same-env rule (`same_env`), the inputs a command is given (`inputs`: files, folders, patterns),
and body poses added to a copy (`poses`)."""
