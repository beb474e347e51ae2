"""Devices to files: the acquisition loop, clocks, sequence counts, the writer, split
parts, snapshots and their triggers, touchdown detection, the recorder, recovery."""
