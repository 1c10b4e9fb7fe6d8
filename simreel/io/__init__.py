"""simreel.io: what keeps written data safe, for every command and room — signals and durable writes (`durable`),
the output rule (`targets`: what may be written where, `--overwrite`), staging a file complete before it takes its
name (`staging`), locks (`lock`) and path checks (`paths`)."""
