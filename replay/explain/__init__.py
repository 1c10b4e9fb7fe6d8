"""The explanation of a diverged replay: events, error growth and the cause the data supports (`explain`)."""
