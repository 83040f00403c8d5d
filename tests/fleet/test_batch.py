"""`bench-ctl batch` on a real Dask cluster (a LocalCluster started here, reached by address as a
user's cluster would be): outputs as the single commands write them, a failing capture recorded
without stopping the others, resumable, the same answer as a capture run alone."""
from __future__ import annotations

import csv
import json

import pytest

from bench_ctl.cli import main
from bench_ctl.fleet.batch import local_cluster
from bench_ctl.fleet.manifest import ManifestError, read_manifest
from bench_ctl.fleet.tasks import VOLATILE_KEYS
from records import assert_round_trip

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
    from bench_ctl.units.unit import reference_unit
    warm_up(reference_unit())
    with local_cluster(2) as c:    # what `batch` starts: on loopback only
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
@pytest.mark.slow
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
    for name in ("result.json", "diagnosis.json"):   # written in a worker: read back here
        assert_round_trip(out / "c1" / name)
    assert float(rows["c1.csv"]["mse_over_floor"]) > 0.5 and rows["c1.csv"]["verdict"] == "none"
    index = (out / "index.html").read_text()
    assert "c1/report.html" in index and "<script>" in index and "http" not in index
    assert "Dask dashboard:" in printed.out
    # the same capture alone, through the single command: the same result
    assert main(["identify", str(fleet / "c1.csv"), "--evals", "200", "--seed", "0", "--no-progress",
                 "--json", str(fleet / "alone.json")]) in (0, 1)
    alone = json.loads((fleet / "alone.json").read_text())
    batched = json.loads((out / "c1" / "result.json").read_text())
    # each names the capture relative to its own file (issue 24 item 14): the same file
    assert (out / "c1" / batched["captures"][0]["path"]).resolve() == (fleet / alone["captures"][0]["path"]).resolve()
    assert _strip(batched, VOLATILE_KEYS + ("path",)) == _strip(alone, VOLATILE_KEYS + ("path",))
    # resumable: nothing to do the second time; a changed capture is done again
    rc2 = main(["batch", str(fleet / "m.csv"), "--out", str(out), "--scheduler", cluster.scheduler_address,
                "--evals", "200"])
    rows2 = {r["capture"].rsplit("/", 1)[-1]: r for r in csv.DictReader((out / "summary.csv").open())}
    assert rc2 == 1 and rows2["c1.csv"]["status"] == "skipped (up to date)"
    assert rows2["c2.csv"]["status"] == "skipped (up to date)" and rows2["bad.csv"]["status"] == "error"


# ---- issue 24: files outside the job (item 9), loopback only (item 10), a missing file is one
# error row (item 16), bounded reads (item 17), Excel's BOM and repeated rows (item 20)

SECRET = "root:$6$N0tAReaLHasH$QeHsecretMARKERsecret:19000:0:99999:7:::"


def _listening(pids):
    """(ip, port) of every TCP socket listening in the processes `pids`, from /proc/net/tcp{,6}
    matched by the sockets' inodes (no psutil needed)."""
    import os
    import socket
    inodes = set()
    for pid in pids:
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
                if target.startswith("socket:["):
                    inodes.add(target[8:-1])
        except OSError:
            continue
    out = []
    for table, fam in (("/proc/net/tcp", socket.AF_INET), ("/proc/net/tcp6", socket.AF_INET6)):
        try:
            lines = open(table).read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            f = line.split()
            if f[3] != "0A" or f[9] not in inodes:          # 0A: LISTEN
                continue
            hexip, hexport = f[1].split(":")
            raw = bytes.fromhex(hexip)
            raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))   # host-order words
            out.append((socket.inet_ntop(fam, raw), int(hexport, 16)))
    return out


def test_our_local_cluster_listens_on_loopback_only():
    """The dashboard listened on 0.0.0.0 (dashboard_address=':0') while the link said 127.0.0.1:
    every socket of the scheduler, nannies, workers and dashboard is on 127.0.0.1."""
    import os

    psutil = pytest.importorskip("psutil")
    with local_cluster(1) as c, distributed.Client(c) as client:
        pids = [os.getpid()] + [p.pid for p in psutil.Process().children(recursive=True)]
        worker_pids = list(client.run(os.getpid).values())
        assert set(worker_pids) <= set(pids)
        found = _listening(pids)
        dash = int(client.dashboard_link.split(":")[2].split("/")[0])
        assert dash in [port for _ip, port in found]                     # the dashboard is among them
        assert len(found) >= 3 and {ip for ip, _ in found} == {"127.0.0.1"}, found


def _secret_fleet(root):
    """A manifest folder with one good capture, rows that point outside (a relative climb to a
    'shadow' file, /etc/shadow), a file inside that is not a capture, a missing one, a repeat."""
    d = root / "job"
    d.mkdir()
    (root / "shadow").write_text(SECRET + "\n")
    (d / "notes.csv").write_text(SECRET + "\nroot:x:0:0:root:/root:/bin/bash\n")
    assert main(["simulate", "-o", str(d / "c1.csv"), "--duration", "3", "--rate", "500", "--seed", "1"]) == 0
    (d / "m.csv").write_text("capture,steps\nc1.csv,identify\n../shadow,identify\n/etc/shadow,identify\n"
                             "notes.csv,identify\nmissing.csv,identify\nc1.csv,identify\n")
    return d


@pytest.mark.timeout(600)
def test_a_manifest_reads_nothing_outside_its_folder_and_echoes_no_content(cluster, tmp_path, capsys):
    d = _secret_fleet(tmp_path)
    out = d / "out"
    rc = main(["batch", str(d / "m.csv"), "--out", str(out), "--scheduler", cluster.scheduler_address,
               "--evals", "100"])
    printed = capsys.readouterr()
    assert rc == 1
    rows = list(csv.DictReader((out / "summary.csv").open()))
    by = {r["capture"].rsplit("/", 1)[-1]: r for r in rows}
    assert len(rows) == 5                                   # the repeated c1.csv row ran once
    assert "line 7 repeats line 2" in printed.out
    assert by["c1.csv"]["status"] in ("ok", "criteria failed")
    outside = [r for r in rows if r["capture"].endswith("shadow")]
    assert len(outside) == 2 and all("outside the manifest's folder" in r["error"] for r in outside)
    assert by["notes.csv"]["status"] == "error" and "not shown" in by["notes.csv"]["error"]
    assert by["missing.csv"]["status"] == "error" and "missing.csv: not found" in by["missing.csv"]["error"]
    for text in ((out / "summary.csv").read_text(), (out / "index.html").read_text(), printed.out, printed.err):
        assert "MARKER" not in text and "/bin/bash" not in text and "N0tAReaLHasH" not in text
    # with --allow-outside the row is read (our own fake file: refused as a capture, still without
    # its content)
    (d / "m2.csv").write_text("capture,steps\n../shadow,identify\n")
    rc = main(["batch", str(d / "m2.csv"), "--out", str(d / "out2"), "--scheduler", cluster.scheduler_address,
               "--evals", "100", "--allow-outside"])
    printed = capsys.readouterr()
    (row,) = csv.DictReader((d / "out2" / "summary.csv").open())
    assert rc == 1 and row["status"] == "error" and "not shown" in row["error"], row
    for text in ((d / "out2" / "summary.csv").read_text(), (d / "out2" / "index.html").read_text(), printed.out,
                 printed.err):
        assert "MARKER" not in text and "N0tAReaLHasH" not in text


@pytest.mark.timeout(600)
def test_a_missing_capture_holdout_or_unit_is_an_error_row_and_the_others_run(cluster, fleet, capsys):
    (fleet / "m16.csv").write_text("capture,holdout,unit,steps\nc1.csv,,,identify\ngone.csv,,,identify\n"
                                   "c2.csv,gone_holdout.csv,,identify+diagnose\nc2.csv,,gone_unit.toml,identify\n")
    out = fleet / "out16"
    rc = main(["batch", str(fleet / "m16.csv"), "--out", str(out), "--scheduler", cluster.scheduler_address,
               "--evals", "100"])
    printed = capsys.readouterr()
    assert rc == 1 and "Traceback" not in printed.err
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["status"] for r in rows][1:] == ["error"] * 3 and rows[0]["status"] in ("ok", "criteria failed")
    assert "gone.csv: not found" in rows[1]["error"]
    assert "column 'holdout': gone_holdout.csv: not found" in rows[2]["error"]
    assert "column 'unit': gone_unit.toml: not found" in rows[3]["error"]
    assert (out / "c1" / "result.json").is_file()


def test_manifest_size_bom_and_repeated_rows(tmp_path, capsys):
    """`batch /dev/zero` was read without end (OOM at 24 GB); a manifest saved by Excel ('CSV UTF-8')
    starts with a byte-order mark and was refused; a repeated row ran twice without a word."""
    import os
    assert main(["batch", "/dev/zero", "--out", str(tmp_path / "o")]) == 2
    assert "not a regular file" in capsys.readouterr().err
    big = tmp_path / "big.csv"
    with open(big, "wb") as f:
        f.truncate(17 << 20)                 # sparse: 17 MiB of nothing, more than a manifest may have
    assert main(["batch", str(big), "--out", str(tmp_path / "o")]) == 2
    assert "more than the 16777216 bytes a manifest may have" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    (tmp_path / "a.csv").write_text("x")
    (tmp_path / "m.csv").write_bytes("\ufeffcapture,model\na.csv,esst1a\na.csv,ESST1A\n".encode("utf-8"))
    notes: list[str] = []
    entries = read_manifest(tmp_path / "m.csv", notes=notes)
    assert len(entries) == 1 and entries[0].model == "ESST1A" and not entries[0].problem
    assert notes == [f"{tmp_path / 'm.csv'}, line 3 repeats line 2 (the same capture, holdout, unit, model, set "
                     "and steps): run once, the second would give the same result"]
    os.mkfifo(tmp_path / "fifo.csv")
    (tmp_path / "m2.csv").write_text("capture\nfifo.csv\n")
    assert "not a regular file" in read_manifest(tmp_path / "m2.csv")[0].problem


@pytest.mark.timeout(900)
@pytest.mark.slow
def test_batch_takes_on_line_captures(cluster, tmp_path, capsys):
    """Issue 27: an on-line capture (P and Q recorded) through identify + report and identify +
    diagnose + report on the cluster."""
    d = tmp_path / "online"
    d.mkdir()
    assert main(["simulate", "--online", "-o", str(d / "on.csv"), "--duration", "4", "--rate", "500",
                 "--amplitude", "0.02", "--width", "2", "--start", "0.5", "--seed", "3"]) == 0
    (d / "m.csv").write_text("capture,steps\non.csv,identify+report\non.csv,identify+diagnose+report\n")
    rc = main(["batch", str(d / "m.csv"), "--out", str(d / "out"), "--scheduler", cluster.scheduler_address,
               "--evals", "200"])
    printed = capsys.readouterr()
    assert rc in (0, 1), printed
    rows = list(csv.DictReader((d / "out" / "summary.csv").open()))
    ok = [r for r in rows if r["status"] in ("ok", "criteria failed")]
    assert len(ok) == 2, (rows, printed)
    for path in (d / "out").glob("*/result.json"):
        result = json.loads(path.read_text())
        assert 0.8e-4 < result["mse"] < 2e-4   # near the 0.01 pu noise at a 200-evaluation budget
        assert result["captures"][0]["path"].endswith("on.csv")
    diagnosis = json.loads(next((d / "out").glob("*/diagnosis.json")).read_text())
    assert diagnosis["verdict"] == "none"   # the capture is the kernel's own machine
