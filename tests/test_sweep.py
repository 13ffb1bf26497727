"""Sweeps (deformgl.sweep): sweep files, variants in one process, on a 2-worker Dask LocalCluster
(llvmpipe in every worker), a worker killed mid-sweep, failed variants in the table."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest

from deformgl.cli import main
from deformgl.errors import InputError
from deformgl.files import read_png

SCENES = Path(__file__).resolve().parents[1] / "scenes"


@pytest.fixture
def jelly(tmp_path):
    """A small copy of the jelly scene (64x48 pixels, no MSAA)."""
    (tmp_path / "assets").mkdir()
    shutil.copy(SCENES / "assets" / "jelly_block.obj", tmp_path / "assets")
    scene = tmp_path / "jelly.toml"
    text = (SCENES / "jelly.toml").read_text().replace("size = [320, 240]", "size = [64, 48]")
    scene.write_text(text.replace("msaa = 4", "msaa = 0"))
    return scene


def write_sweep(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "s.toml"
    path.write_text('scene = "jelly.toml"\n' + body)
    return path


def test_sweep_files_give_the_product_and_the_listed_variants(jelly, tmp_path):
    from deformgl.sweep.sweepfile import load_sweep

    spec = load_sweep(write_sweep(tmp_path, '[set]\n"physics.steps" = 10\n[product]\n"physics.integrator" = '
                                  '["verlet", "rk4"]\n"grid.nodes_along_longest" = [5, 6, 7]\n[[variant]]\n'
                                  'name = "stiff"\n"physics.stiffness" = 50\n'))
    assert [v.name for v in spec.variants] == [f"v{i:02d}" for i in range(6)] + ["stiff"]
    assert spec.variants[4].overrides == {"physics.steps": 10, "physics.integrator": "rk4",
                                          "grid.nodes_along_longest": 6}
    assert spec.variants[6].overrides == {"physics.steps": 10, "physics.stiffness": 50}
    assert spec.scene == jelly.resolve()
    shipped = load_sweep(Path(__file__).resolve().parents[1] / "examples" / "sweeps" / "jelly16.toml")
    assert len(shipped.variants) == 16 and shipped.scene.name == "jelly.toml"  # a shipped scene, by name
    assert shipped.variants[15].overrides["physics.integrator"] == "rk4"
    for body, message in (("[product]\n", "no variants"), ("bogus = 1\n[[variant]]\n", "bogus: unknown key"),
                          ('[product]\n"physics.dt" = 3\n', "each an array of values"),
                          ('outputs = ["gif"]\n[[variant]]\n', "outputs: must be an array of"),
                          ('[[variant]]\nname = "sweep"\n', "'sweep' is reserved"),
                          ('[[variant]]\nname = ".hidden"\n', "not starting with '.'")):
        with pytest.raises(InputError, match=message):
            load_sweep(write_sweep(tmp_path, body))


def test_variants_in_one_process_with_a_failed_one_in_the_table(ctx, jelly, tmp_path, capsys):
    from deformgl.sweep.runner import sweep_scene

    out = tmp_path / "out"
    result = sweep_scene(jelly, out, variants=[{"physics.steps": 20}, {"physics.steps": 20, "physics.dt": -1},
                                               {"name": "boom", "physics.dt": 0.2, "physics.steps": 40,
                                                "physics.safety.unstable": "run", "physics.safety.check_every": 10}],
                         workers=0, ctx=ctx)
    ok, bad, boom = result.records
    assert ok["status"] == "ok" and ok["steps"] == 20 and read_png(out / "v00.png").shape == (48, 64, 3)
    assert json.loads((out / "v00.json").read_text())["steps"] == 20
    assert bad["status"] == "input error" and "physics.dt: must be > 0, got -1" in bad["error"]
    assert boom["status"] == "failed" and boom["error"]
    assert not (out / "v01.png").exists() and not (out / "boom.png").exists()
    with open(out / "sweep.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["variant"] for r in rows] == ["v00", "v01", "boom"]
    assert rows[1]["status"] == "input error" and rows[1]["physics.dt"] == "-1" and rows[0]["nodes"] == str(ok["nodes"])
    sheet = read_png(out / "sweep.png")
    assert sheet.shape[1] == 3 * 200 and sheet.std() > 0
    # the deformed mesh of a mapped variant, and only the files asked for
    import trimesh

    meshed = sweep_scene(jelly, tmp_path / "m", variants=[{"name": "bent", "physics.steps": 20, "mapping.mode": "constant"}],
                         outputs=("mesh", "record"), workers=0, ctx=ctx, table=False)
    assert meshed.records[0]["status"] == "ok", meshed.records[0]["error"]
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["bent.json", "bent.ply"]
    assert meshed.records[0]["outputs"] == [str(tmp_path / "m" / "bent.ply")]
    assert json.loads((tmp_path / "m" / "bent.json").read_text())["outputs"] == [str(tmp_path / "m" / "bent.ply")]
    assert len(trimesh.load(tmp_path / "m" / "bent.ply", process=False).faces) > 0


@pytest.mark.sweep
def test_dask_sweep_on_two_workers_matches_the_one_process_sweep(ctx, jelly, tmp_path, capsys):
    sweep = write_sweep(tmp_path, '[set]\n"physics.steps" = 30\n[product]\n"physics.integrator" = '
                                  '["verlet", "semi-implicit"]\n"grid.nodes_along_longest" = [6, 8]\n')
    code = main(["sweep", str(sweep), "-o", str(tmp_path / "dask"), "--workers", "2", "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "sweep of 4 variants on LocalCluster (2 workers): 4 ok, 0 failed" in err
    code = main(["sweep", str(sweep), "-o", str(tmp_path / "one"), "--workers", "0", "--quiet", "--no-sheet"])
    assert code == 0, capsys.readouterr().err
    dask = json.loads((tmp_path / "dask" / "sweep.json").read_text())
    one = json.loads((tmp_path / "one" / "sweep.json").read_text())
    assert [r["variant"] for r in dask] == [r["variant"] for r in one] == ["v00", "v01", "v02", "v03"]
    assert {r["worker_pid"] for r in dask}.isdisjoint({os.getpid()})  # they ran in the worker processes
    for a, b in zip(dask, one):
        assert (a["nodes"], a["steps"], a["integrator"]) == (b["nodes"], b["steps"], b["integrator"])
        # the same variant renders the same image in a worker and here (the same llvmpipe)
        diff = np.abs(read_png(tmp_path / "dask" / f"{a['variant']}.png").astype(int)
                      - read_png(tmp_path / "one" / f"{a['variant']}.png"))
        assert diff.max() <= 1


@pytest.mark.sweep
def test_a_worker_killed_mid_sweep_is_replaced_and_every_variant_is_in_the_table_once(ctx, jelly, tmp_path):
    from distributed import Client, LocalCluster

    from deformgl.sweep.runner import sweep_scene

    out = tmp_path / "out"
    killed: dict[str, object] = {}
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=50)
    client = Client(cluster)
    try:
        pids = client.run(os.getpid)  # worker address -> process id

        def kill_a_busy_worker(record):
            if killed:
                return
            for address, keys in client.processing().items():
                if keys:  # a worker running a variant now: SIGKILL its process mid-task
                    killed.update(pid=pids[address], keys=set(keys))
                    os.kill(pids[address], signal.SIGKILL)
                    return

        result = sweep_scene(jelly, out, product={"physics.steps": [200, 210, 220, 230, 240, 250, 260, 270]},
                             client=client, on_result=kill_a_busy_worker)
    finally:
        client.close()
        cluster.close()
    assert killed, "no worker was busy when the first result came"
    assert [r["status"] for r in result.records] == ["ok"] * 8, [r.get("error") for r in result.records]
    assert [r["variant"] for r in result.records] == [f"v{i:02d}" for i in range(8)]
    assert [r["steps"] for r in result.records] == [200, 210, 220, 230, 240, 250, 260, 270]
    # the variant the killed worker was running was run again, by a live worker
    rerun = [r for r in result.records if any(r["variant"] in key for key in killed["keys"])]  # type: ignore[union-attr]
    assert rerun and all(r["worker_pid"] != killed["pid"] for r in rerun)
    # every variant's files once, whole, and no temporary left by the killed worker
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"v{i:02d}.{ext}" for i in range(8) for ext in ("png", "json")] + ["sweep.csv", "sweep.json", "sweep.png"])
    for i in range(8):
        assert read_png(out / f"v{i:02d}.png").shape == (48, 64, 3)
        assert json.loads((out / f"v{i:02d}.json").read_text())["steps"] == 200 + 10 * i


@pytest.mark.sweep
def test_workers_are_pinned_to_their_devices_by_name(ctx, jelly, tmp_path, monkeypatch):
    """devices=[0, 7]: worker 0 renders on EGL device 0 (llvmpipe's), worker 1 on device 7, which
    this machine does not have: its variants are rows with the GL error, not a failed sweep."""
    from deformgl.sweep import runner

    assert runner.detect_gpus() is None or len(runner.detect_gpus() or []) >= 2
    result = runner.sweep_scene(jelly, tmp_path / "out", product={"physics.steps": [10, 20, 30, 40, 50, 60]},
                                workers=2, devices=[0, 7], outputs=("record",))
    devices = {r["device"] for r in result.records}
    assert devices == {"0", "7"}, devices
    for r in result.records:
        if r["device"] == "0":
            assert r["status"] == "ok" and "llvmpipe" in r["renderer"]
        else:
            assert r["status"] == "failed" and "EGL device 7" in r["error"]
    assert not (tmp_path / "out" / "sweep.png").exists()  # no "png" output: no contact sheet


@pytest.mark.sweep
def test_bench_trade_on_dask_workers_measures_the_same_runs_as_in_process(ctx):
    """One task per workload: the same rows (integrators, dts, steps) with the same errors as the
    in-process study; only the costs differ (measured while the workloads share the machine)."""
    from deformgl.bench.trade import trade_study
    from deformgl.sweep.trade_tasks import distributed_trade

    backends = ("numpy",)  # (the GPU backends' rows go the same way; numpy keeps the test short)
    here = trade_study(ctx, quick=True, backends=backends, fractions=(0.6,))
    there = distributed_trade(quick=True, backends=backends, fractions=(0.6,), workers=2)
    key = [(r.workload, r.backend, r.integrator, r.steps, r.dt, r.status) for r in here.rows]
    assert [(r.workload, r.backend, r.integrator, r.steps, r.dt, r.status) for r in there.rows] == key
    for a, b in zip(here.rows, there.rows):
        assert b.rms == pytest.approx(a.rms, rel=1e-6, abs=1e-12) or (np.isnan(a.rms) and np.isnan(b.rms))
        assert b.ms_per_step > 0
    assert [r.workload for r in there.references] == [r.workload for r in here.references]
    assert "2 workloads on 2 Dask workers at once" in there.machine


def test_without_dask_the_sweep_says_which_extra_to_install(jelly, tmp_path, monkeypatch, capsys):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)
    sweep = write_sweep(tmp_path, '[[variant]]\n"physics.steps" = 1\n')
    code = main(["sweep", str(sweep), "-o", str(tmp_path / "out"), "--workers", "2"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "needs Dask distributed (the 'sweep' extra: pip install 'deformgl[sweep]')" in err
    assert "--workers 0 runs the variants in this process" in err
    assert not (tmp_path / "out").exists()  # refused before any work
