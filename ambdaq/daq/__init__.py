"""Recorder, MCAP layout and schemas, fast reader, recovery and export."""

from .reader import Recording, TopicData, load

__all__ = ["Recording", "TopicData", "load"]
