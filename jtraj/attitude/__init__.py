"""Planning with Attitude: Wahba problem and rigid-body benchmarks."""
