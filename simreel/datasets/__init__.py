"""simreel.datasets: operations on whole recordings, above the formats — copy, convert between formats and recover
(`copy`), merge, filter and digests (`dataset`), the same-env rule (`same_env`), the inputs a command is given
(`inputs`: files, folders, patterns), and body poses added to a copy (`poses`)."""
