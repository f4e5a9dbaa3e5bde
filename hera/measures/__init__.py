"""Measures that ship with the framework (observers for fault-tolerance runs, a beacon for
benchmarks) and their application (:mod:`.app`). A plugin layer like any other: the runtime
finds them through the entry points."""
