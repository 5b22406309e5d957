"""The commands' libraries: benchmark grids, sweeps, reports and their figures, the rendered docs, control."""
