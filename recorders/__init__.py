"""simreel.recorders: the recording room — `RecordWrapper` and what it samples each step."""

from simreel.recorders.record_wrapper import RecordWrapper, StateLayoutChanged

__all__ = ["RecordWrapper", "StateLayoutChanged"]
