"""GA fitness on Ray: same results as the local path, worker and driver faults, paper scale.

One local 2-CPU cluster serves the whole module (starting one costs 5-20 s on the shared
machine); the driver-fault test starts one more in a killed subprocess.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mask_profiles import make_profile
from thintact_masks.devices import scaled_profile
from thintact_masks.errors import MaskDesignError
from thintact_masks.fitness import FitnessEvaluator
from thintact_masks.ga import GAConfig, load_checkpoint, run_ga
from thintact_masks.optimize import optimize_mask

from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.host.blas import blas_threads

ray = pytest.importorskip("ray")
from thintact_masks.ray_pool import RayFitnessPool, connect  # noqa: E402

#: the Ray task's process title while it runs (Ray names it after the function)
TASK_TITLE = b"ray::evaluate_genes"
#: a scaled-down paper device: ~20-40 ms per evaluation, so tasks last long enough to be hit
SMALL_SCALE = 0.2


@pytest.fixture(scope="module")
def cluster_address():
    """A private local Ray cluster of 2 CPUs for this module; its GCS address."""
    if ray.is_initialized():
        pytest.skip("Ray is already initialised in this process")
    assert connect("auto", num_cpus=2)
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


@pytest.fixture(scope="module")
def small_evaluator() -> FitnessEvaluator:
    return FitnessEvaluator(scaled_profile(load_profile("thintact-paper"), SMALL_SCALE))


def _genes(n: int, k: int, seed: int = 0) -> np.ndarray:
    return (2 * np.random.default_rng(seed).integers(0, 2, (n, k)) - 1).astype(np.int8)


def test_local_cluster_listens_on_loopback_only(cluster_address) -> None:
    assert cluster_address.startswith("127.0.0.1:")
    assert ray.util.get_node_ip_address() == "127.0.0.1"


def test_pool_gives_the_local_fitness_and_puts_the_evaluator_once(cluster_address,
                                                                  monkeypatch) -> None:
    ev = FitnessEvaluator(make_profile(), 40)
    puts = []
    real_put = ray.put
    monkeypatch.setattr(ray, "put", lambda v, **kw: puts.append(type(v)) or real_put(v, **kw))
    genes = _genes(9, 40)
    with blas_threads(1):
        local = np.array([ev.fitness(g) for g in genes])
    with RayFitnessPool(ev, batch_size=2, device="cpu") as pool:
        first = pool(genes)
        second = pool(genes[::-1])
        assert pool.last.tasks == 5 and pool.last.genes == 9  # batches of 2 genes
        assert [s.stop - s.start for s in pool.batches(9)] == [2, 2, 2, 2, 1]
    assert puts == [FitnessEvaluator]  # put once; tasks got its reference
    np.testing.assert_array_equal(first, local)
    np.testing.assert_array_equal(second, local[::-1])
    assert ray.is_initialized()  # a pool on a cluster it did not start leaves it running


def test_same_seed_same_run_with_one_two_workers_and_locally(cluster_address,
                                                             small_evaluator) -> None:
    ev, config = small_evaluator, GAConfig(population=8, generations=3, seed=4)
    with blas_threads(1):
        local = run_ga(ev.K, config, ev.fitness)
    runs = {}
    pids = {}
    # cpus_per_task=2 on the 2-CPU cluster: one task at a time, i.e. one worker
    for workers, cpus_per_task in ((1, 2.0), (2, 1.0)):
        with RayFitnessPool(ev, batch_size=2, cpus_per_task=cpus_per_task, device="cpu") as pool:
            runs[workers] = run_ga(ev.K, config, ev.fitness, batch_fitness=pool)
            pids[workers] = set().union(*(s.worker_pids for s in pool.history))
            assert pool.cluster_slots() == workers
    assert len(pids[2]) == 2  # both workers evaluated genes
    for state in runs.values():
        np.testing.assert_array_equal(state.best_phi, local.best_phi)
        np.testing.assert_array_equal(state.population, local.population)
        assert state.best_history == local.best_history
        assert state.mean_history == local.mean_history


def _kill_first_running_task(killed: list[int], stop: threading.Event) -> None:
    """Kill (SIGKILL) the first worker process seen running an evaluation task."""
    uid = os.getuid()
    while not stop.is_set() and not killed:
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                if os.stat(f"/proc/{entry}").st_uid != uid:
                    continue
                with open(f"/proc/{entry}/cmdline", "rb") as f:
                    title = f.read()
            except OSError:
                continue
            if title.startswith(TASK_TITLE):
                os.kill(int(entry), signal.SIGKILL)
                killed.append(int(entry))
                return
        time.sleep(0.005)


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="finds worker processes in /proc")
def test_a_killed_worker_costs_a_retry_not_the_run(cluster_address, small_evaluator) -> None:
    ev, config = small_evaluator, GAConfig(population=8, generations=2, seed=1)
    with blas_threads(1):
        local = run_ga(ev.K, config, ev.fitness)
    with RayFitnessPool(ev, batch_size=4, max_retries=2, device="cpu") as pool:
        pool(_genes(2, ev.K))  # workers up and holding the evaluator
        killed: list[int] = []
        stop = threading.Event()
        killer = threading.Thread(target=_kill_first_running_task, args=(killed, stop))
        killer.start()
        try:
            state = run_ga(ev.K, config, ev.fitness, batch_fitness=pool)
        finally:
            stop.set()
            killer.join()
        assert killed, "no running evaluation task was found to kill"
    np.testing.assert_array_equal(state.best_phi, local.best_phi)
    assert state.best_history == local.best_history


def test_lost_tasks_are_one_line_errors(cluster_address, small_evaluator) -> None:
    with RayFitnessPool(small_evaluator, batch_size=8, max_retries=0, device="cpu") as pool:
        killed: list[int] = []
        stop = threading.Event()
        killer = threading.Thread(target=_kill_first_running_task, args=(killed, stop))
        killer.start()
        try:
            with pytest.raises(MaskDesignError, match="checkpoint"):
                pool(_genes(16, small_evaluator.K))
        finally:
            stop.set()
            killer.join()
        assert killed
        with pytest.raises(MaskDesignError, match="fitness task failed.*shape"):
            pool(_genes(2, small_evaluator.K + 1))  # an error inside the task: not retried


def _driver(out: Path, ray_arg: str, generations: int) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "thintact_sdk.apps.cli.main", "mask", "optimize",
           "--profile", "thintact-paper", "--scale", str(SMALL_SCALE), "--population", "8",
           "--generations", str(generations), "--seed", "3", "--out", str(out),
           "--no-progress", "--workers", "1", "--ray", ray_arg]
    # its own process group: killing it takes down its own local cluster too (a lost machine)
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)


def _kill_at_generation(proc: subprocess.Popen, out: Path, generation: int,
                        timeout_s: float = 120.0) -> int:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        state = load_checkpoint(out) if (out / "checkpoint.npz").is_file() else None
        if state is not None and state.generation >= generation:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            return state.generation
        if proc.poll() is not None:
            pytest.fail(f"driver ended before generation {generation}: {proc.stderr.read()!r}")
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    pytest.fail(f"driver did not reach generation {generation} in {timeout_s} s")


def test_a_killed_driver_resumes_on_another_and_on_the_same_cluster(cluster_address,
                                                                   tmp_path) -> None:
    # generations take tens of ms: room after the second cut so that a poller starved by a
    # busy host still kills the second driver before it finishes (16 was not always enough:
    # a fresh-clone CI run saw the second driver reach 16 of 16 before its kill)
    generations = 32
    profile = load_profile("thintact-paper")
    config = GAConfig(population=8, generations=generations, seed=3)
    reference, _ = optimize_mask(profile, config, scale=SMALL_SCALE, out_dir=tmp_path / "ref",
                                 fitness_device="cpu")
    ref = load_checkpoint(tmp_path / "ref")
    out = tmp_path / "run"
    # 1. a driver on its own local cluster (--ray auto) dies with its cluster
    cut1 = _kill_at_generation(_driver(out, "auto", generations), out, 2)
    # 2. a new driver continues on another cluster (this module's, by address) and dies
    cut2 = _kill_at_generation(_driver(out, cluster_address, generations), out, cut1 + 2)
    assert cut1 < cut2 < generations
    # 3. resumed once more on that same cluster, here, to the end
    mask, record = optimize_mask(profile, config, scale=SMALL_SCALE, out_dir=out,
                                 ray=cluster_address, fitness_device="cpu")
    final = load_checkpoint(out)
    assert ref is not None and final is not None and final.generation == generations
    np.testing.assert_array_equal(mask.phi, reference.phi)
    np.testing.assert_array_equal(final.population, ref.population)
    assert final.best_history == ref.best_history
    assert final.rng_state == ref.rng_state
    assert record["history"]["best"] == ref.best_history


def test_a_paper_scale_generation_on_ray(cluster_address) -> None:
    """K = 770 on the full-size paper device (Pc 1024×400, Qc 1280×512); 4 individuals."""
    ev = FitnessEvaluator(load_profile("thintact-paper"), 770)
    config = GAConfig(population=4, generations=1, seed=0)
    with RayFitnessPool(ev, batch_size=1, device="cpu") as pool:
        state = run_ga(770, config, ev.fitness, batch_fitness=pool)
        # the initial population on Ray; a child equal to a known gene is not evaluated again
        assert pool.history[0].genes == 4
        assert pool.cluster_slots() == 2
    assert state.generation == 1 and state.population.shape == (4, 770)
    with blas_threads(1):
        assert state.best_fitness == ev.fitness(state.best_phi)



def test_cli_ray_run_equals_the_local_run(cluster_address, tmp_path) -> None:
    """`thintact mask optimize --ray ADDRESS` on a running cluster: the same design, history and
    checkpoint-resumable output as the local path (the GA's randomness stays in the driver)."""
    import json

    from thintact_sdk.apps.cli.main import main
    from thintact_sdk.formats.profiles import write_profile

    tiny_profile_file = write_profile(make_profile(), tmp_path / "tiny.yaml")
    common = ["mask", "optimize", "--profile", str(tiny_profile_file), "--population", "6",
              "--generations", "2", "--seed", "3", "--no-progress", "--device", "cpu"]
    assert main([*common, "--out", str(tmp_path / "local")]) == 0
    assert main([*common, "--out", str(tmp_path / "ray"), "--ray", cluster_address,
                 "--ray-batch", "2"]) == 0
    local, on_ray = (json.loads((tmp_path / d / "design.json").read_text()) for d in ("local", "ray"))
    assert on_ray["phi"] == local["phi"]
    assert on_ray["history"] == local["history"]
    assert main([*common, "--out", str(tmp_path / "bad"), "--ray-batch", "2"]) == 2  # needs --ray
