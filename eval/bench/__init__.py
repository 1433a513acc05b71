"""The benchmarks (``make bench-*``), each printing a ratio against a reference measured in
the same run; the top layer (they may run anything below them)."""
