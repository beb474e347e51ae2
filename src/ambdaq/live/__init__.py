"""What a recording shows while it runs, for any consumer: the figures of the live view
(:mod:`.view`) and the Foxglove WebSocket server (:mod:`.foxglove`). The recorder hands them its
blocks (``on_block``); the command line draws the view (``cli/live.py``)."""
