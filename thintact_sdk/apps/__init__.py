"""Applications over the library: the ``thintact`` CLI, the browser viewer, the Foxglove live server and the benchmarks."""
