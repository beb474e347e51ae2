"""Recorder, MCAP layout and schemas, recordings opened once, fast reader, recovery and export."""

from ..mcap.memory import release_memory
from ..mcap.reader import TopicData
from .recording import DeviceInfo, Recording, load, open_recording

__all__ = ["DeviceInfo", "Recording", "TopicData", "load", "open_recording", "release_memory"]
