"""The entry: the Python API (``api``), the one room where every command's argv is handled (``cli``), and the
``--help`` groups."""
