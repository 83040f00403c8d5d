"""`bench-ctl batch` on a real Dask cluster (a LocalCluster started here, reached by address as a
user's cluster would be): outputs as the single commands write them, a failing capture recorded
without stopping the others, resumable, the same answer as a capture run alone."""
from __future__ import annotations

import csv
import json
import logging

import pytest

from bench_ctl.cli import main
from bench_ctl.fleet.batch import WORKER_ENV, local_cluster
from bench_ctl.fleet.manifest import ManifestError, read_manifest
from bench_ctl.fleet.tasks import VOLATILE_KEYS

distributed = pytest.importorskip("distributed")


def _strip(d, drop=VOLATILE_KEYS):
    if isinstance(d, dict):
        return {k: _strip(v, drop) for k, v in d.items() if k not in drop}
    if isinstance(d, list):
        return [_strip(v, drop) for v in d]
    return d


@pytest.fixture(scope="module")
def cluster():
    # the kernel compiled (or loaded) here first, so the workers load numba's disk cache instead of
    # compiling it twice at once beside this process (on a fresh checkout that took the test past
    # its timeout on this 2-core machine with another job running)
    from bench_ctl.identification.identify import warm_up
    from bench_ctl.model.unit import reference_unit
    warm_up(reference_unit())
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  env=WORKER_ENV, silence_logs=logging.WARNING) as c:
        yield c


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    for i in (1, 2):
        assert main(["simulate", "-o", str(d / f"c{i}.csv"), "--duration", "3", "--rate", "500",
                     "--seed", str(i)]) == 0
    (d / "bad.csv").write_text("time,usetp,efd\n")
    (d / "m.csv").write_text("capture,steps\nc1.csv,\nbad.csv,\nc2.csv,identify+report\n")
    return d


def _worker_settings():
    import os

    import dask
    return (dask.config.get("distributed.worker.profile.enabled"), os.environ.get("MALLOC_TRIM_THRESHOLD_"),
            os.environ.get("NUMBA_NUM_THREADS"))


def test_our_local_cluster_runs_workers_without_profiler_or_forced_trim():
    """What `batch` starts: workers whose config has the statistical profiler off (a DASK_* variable
    in their environment would be overridden by the parent's config) and glibc's own malloc trim."""
    with local_cluster(1) as c, distributed.Client(c) as client:
        assert list(client.run(_worker_settings).values()) == [(False, None, "1")]


def test_manifest_errors_name_line_and_column(tmp_path):
    (tmp_path / "m.csv").write_text("capture,color\na.csv,red\n")
    with pytest.raises(ManifestError, match="line 1: unknown column"):
        read_manifest(tmp_path / "m.csv")
    (tmp_path / "m.csv").write_text("capture,steps\na.csv,identify+fly\n")
    with pytest.raises(ManifestError, match="line 2, column 'steps'"):
        read_manifest(tmp_path / "m.csv")
    (tmp_path / "m.csv").write_text("capture,set\na.csv,KAVR=250;TR=0.01\na.csv,\n")
    entries = read_manifest(tmp_path / "m.csv")
    assert entries[0].overrides == ("KAVR=250", "TR=0.01") and entries[0].name != entries[1].name


@pytest.mark.timeout(900)   # a fresh checkout compiles the kernel once (~100-200 s here)
def test_batch_on_a_cluster_by_address(cluster, fleet, capsys):
    out = fleet / "out"
    rc = main(["batch", str(fleet / "m.csv"), "--out", str(out), "--scheduler", cluster.scheduler_address,
               "--evals", "200"])
    printed = capsys.readouterr()
    assert rc == 1, printed  # one capture errors: reported, the others done
    rows = {r["capture"].rsplit("/", 1)[-1]: r for r in csv.DictReader((out / "summary.csv").open())}
    assert rows["c1.csv"]["status"] in ("ok", "criteria failed")
    assert rows["bad.csv"]["status"] == "error" and "header only" in rows["bad.csv"]["error"]
    assert rows["c2.csv"]["diagnosis"] == ""  # its steps were identify+report
    for name in ("result.json", "diagnosis.json", "report.html"):
        assert (out / "c1" / name).is_file()
    assert float(rows["c1.csv"]["mse_over_floor"]) > 0.5 and rows["c1.csv"]["verdict"] == "none"
    index = (out / "index.html").read_text()
    assert "c1/report.html" in index and "<script>" in index and "http" not in index
    assert "Dask dashboard:" in printed.out
    # the same capture alone, through the single command: the same result
    assert main(["identify", str(fleet / "c1.csv"), "--evals", "200", "--seed", "0", "--no-progress",
                 "--json", str(fleet / "alone.json")]) in (0, 1)
    alone = json.loads((fleet / "alone.json").read_text())
    batched = json.loads((out / "c1" / "result.json").read_text())
    assert _strip(batched) == _strip(alone)
    # resumable: nothing to do the second time; a changed capture is done again
    rc2 = main(["batch", str(fleet / "m.csv"), "--out", str(out), "--scheduler", cluster.scheduler_address,
                "--evals", "200"])
    rows2 = {r["capture"].rsplit("/", 1)[-1]: r for r in csv.DictReader((out / "summary.csv").open())}
    assert rc2 == 1 and rows2["c1.csv"]["status"] == "skipped (up to date)"
    assert rows2["c2.csv"]["status"] == "skipped (up to date)" and rows2["bad.csv"]["status"] == "error"
