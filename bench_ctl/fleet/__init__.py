"""Fleets: many captures identified, diagnosed and reported at once on Dask (docs/fleets.md).

`manifest.read_manifest` reads the CSV that lists the captures; `tasks` runs one step of one
capture exactly as the single command does (`bench-ctl identify` / `diagnose` / `report`, same
argv, same files); `batch.run_batch` puts the steps on a Dask cluster (a LocalCluster it starts,
or an existing one by address), skips what is up to date, records failures without stopping the
others, and writes `summary.csv` and `index.html`.
"""
