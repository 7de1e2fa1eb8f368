"""Campaigns: one scenario at many points (grid and seeded random), on local processes or Dask."""
