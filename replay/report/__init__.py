"""The report of a replay: each episode's (`report`), the streaming, resumable report log (`log`) and the counts over a
run (`tally`)."""
