"""The ``thintact`` command line."""
