"""Multi-step jobs, callable from Python without the command line: identify runout and check it
is gone, measure and estimate frequency responses, run a base-motion campaign and fit its
compensators, push coefficients verified, compare LMS schedules on a run-up.  They may use every
other part; the command line (:mod:`ambdaq.cli`) only parses, calls them and prints."""
