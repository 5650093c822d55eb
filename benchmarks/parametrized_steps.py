"""Where the parametrized forward filter spends its time: the step by kind, the table's RK4 fallback, the algebra (issue 18.1).

On `benchmarks/fit_core.py`'s tracks (``--sample minbias``: 40 minimum-bias events at
ν = 7.6, long truth tracks and their seeds; ``pigun``), one process, CPU time
(`time.process_time`), minimum over ``--repeat`` after a warm-up:

1. every node-to-node step of the parametrized extrapolator (`pkf.fit.extrapolator.extrapolate`:
   state, Jacobian, noise) grouped by the subdetectors it joins, each group timed alone from
   the states a forward chain of steps gives (no Kalman update: the states are the seeds
   carried by the steps): ns per step and its share of ns per node of the whole sample;
2. the UT→SciFi steps split by whether the table covers the state (|q/p′|·p_min ≤ w_max,
   q/p′ the q/p after the tuned energy loss upstream of the magnet) or the step falls back to
   RK4 through the field map (`pkf.params.transport._apply`);
3. the forward filter built up in one kernel over all tracks: the steps alone, + the
   covariance transport F·P·Fᵀ + Q (`pkf.physics.linalg.transport_cov`), + the measurement
   updates (`pkf.fit.kalman.scalar_update`): ns per node of each. The fit's own forward filter
   (`pkf.fit.kalman._fit_once`) also copies each node's prediction, covariance and Jacobian
   into the lanes of the backward filter.

Measured (2026-12-06, AMD EPYC VM, minimum bias, 257,055 nodes, 8,907 tracks; fit_core's full
fit ~306 ns per node). At 54be5f1: the steps 93.5–104 ns per node (VELO→VELO 37 ns per step,
SciFi→SciFi 73, UT→UT 69, VELO→UT 100, UT→SciFi 1,314: the table 853 on 8,246 steps, the RK4
fallback 32.8 µs on 102 steps, 13 ns per node), + covariance 126, + updates 143. At 3adbce2
(the table's columns as SIMD rows, the crossed VELO layers inlined), three runs: VELO→VELO
28–31, the table 721–966, the fallback 33–35 µs (13–14 ns per node), the steps 90.0–91.1,
+ covariance 114–131, + updates 133–188 ns per node. Runs on this machine differ by up to ×2
per group (SciFi→SciFi 71–105, UT→UT 69–160): compare code versions in one process, both
orders of compilation, against an A/B of identical code, not separate runs.

``--against CHECKOUT`` does that: CHECKOUT's pkf, imported beside this one as
``pkf_base_<digest>`` (`twin.load_twin`), builds its own parametrized extrapolator, whose
record type is registered here with the twin's step (`register_extrapolator`), so the
kernels above time both extrapolators on the same states (this checkout's chain; the
covariance transport and the update are this checkout's on both sides: the comparison is of
the steps). The two alternate for ``--rounds`` rounds (each the minimum over ``--repeat``);
printed per group: both minima and medians, the median over the rounds of new/base. The null comparison (2026-12-06,
``--against .``, 4 rounds of 3): new/base 0.97–1.00 for the step groups (ranges within
0.92–1.07), 1.009–1.058 for the forward filter's stages (ranges up to 1.19): read a
difference against these. Where the machine was slow, UT→UT measured 95–135 ns per step
against SciFi→SciFi's 56–81, but 65 against 66 with each group's states copied to a compact
array first (in one process): 3–4 UT nodes per track lie scattered, the SciFi's 12 in a
row, so the UT step costs what the SciFi one does.

    python benchmarks/parametrized_steps.py [--sample minbias] [--repeat 7] [--json out.json]
    python benchmarks/parametrized_steps.py --against ../base [--rounds 6] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numba as nb
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fit_compare  # noqa: E402

from pkf.fit.extrapolator import extrapolate  # noqa: E402
from pkf.fit.kalman import scalar_update  # noqa: E402
from pkf.geometry import load_geometry  # noqa: E402
from pkf.jit import NO_REFCOUNT, stack_array  # noqa: E402
from pkf.params.ut_to_scifi import META_P_MIN, META_W_MAX  # noqa: E402
from pkf.physics.linalg import copy5, copy55, transport_cov  # noqa: E402

SUBDETECTORS = ("velo", "ut", "scifi")
STAGES = ("steps", "+ covariance", "+ updates")


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def chain_states(ext, offsets, z, seeds, states_in):
    """states_in[k]: the state each step k − 1 → k starts from, the seed carried by the steps."""
    work = stack_array((6, 5, 5))
    state = stack_array((5,))
    jac = stack_array((5, 5))
    noise = stack_array((5, 5))
    for t in range(offsets.size - 1):
        copy5(seeds[t], state)
        for k in range(offsets[t] + 1, offsets[t + 1]):
            copy5(state, states_in[k])
            extrapolate(ext, states_in[k], z[k - 1], z[k], state, jac, noise, work)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def time_steps(ext, nodes, z, states_in):
    """The steps into `nodes` (each k − 1 → k from states_in[k]); a checksum of the outputs."""
    work = stack_array((6, 5, 5))
    out = stack_array((5,))
    jac = stack_array((5, 5))
    noise = stack_array((5, 5))
    checksum = 0.0
    for k in nodes:
        extrapolate(ext, states_in[k], z[k - 1], z[k], out, jac, noise, work)
        checksum += out[0] + jac[0, 4] + noise[0, 0]
    return checksum


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def forward_filter(ext, offsets, z, seeds, seed_covs, n_meas, hx, hy, m, sigma, stage):
    """The forward filter over all tracks up to `stage` (0: steps, 1: + covariance, 2: +
    updates); the per-node prediction, Jacobian and noise go to one track's scratch. A checksum."""
    work = stack_array((6, 5, 5))
    state = stack_array((5,))
    cov = stack_array((5, 5))
    tmp = stack_array((5, 5))
    pred = stack_array((5,))
    jac = stack_array((5, 5))
    noise = stack_array((5, 5))
    checksum = 0.0
    for t in range(offsets.size - 1):
        copy5(seeds[t], state)
        copy55(seed_covs[t], cov)
        for k in range(offsets[t], offsets[t + 1]):
            if k > offsets[t]:
                extrapolate(ext, state, z[k - 1], z[k], pred, jac, noise, work)
                copy5(pred, state)
                if stage >= 1:
                    transport_cov(jac, cov, tmp, cov)
                    for i in range(5):
                        for j in range(5):
                            cov[i, j] += noise[i, j]
            if stage >= 2:
                for j in range(n_meas[k]):
                    increment, _ = scalar_update(state, cov, hx[k, j], hy[k, j], m[k, j], sigma[k, j] ** 2)
                    checksum += increment
        checksum += state[4] + cov[4, 4]
    return checksum


def best_seconds(repeat: int, fn, *args) -> float:
    fn(*args)  # warm-up (compiles or loads the kernel)
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn(*args)
        times.append(time.process_time() - t0)
    return min(times)


def step_groups(ext, batch, geometry, states_in) -> dict[str, np.ndarray]:
    """Node indices k of the steps k − 1 → k, by the subdetectors they join; the UT→SciFi ones
    also by table or RK4 fallback."""
    n = batch.z.size
    first = np.zeros(n, dtype=bool)
    first[batch.offsets[:-1]] = True
    k = np.flatnonzero(~first)
    sub = geometry.layer_subdetector[batch.layer]
    groups = {}
    for a, name_a in enumerate(SUBDETECTORS):
        for b, name_b in enumerate(SUBDETECTORS):
            sel = k[(sub[k - 1] == a) & (sub[k] == b)]
            if sel.size:
                groups[f"{name_a} → {name_b}"] = sel
    ut_scifi = groups.get("ut → scifi", np.zeros(0, dtype=np.int64))
    # the table step leaves from the UT's last layer (its slot holds the energy loss); the
    # layer steps before it keep q/p, so the q/p at the last UT hit decides
    slot = ext.sub_last[ext.layer_sub[batch.layer[ut_scifi - 1]]]
    eloss = ext.extrapolation[slot, 0]
    qop = states_in[ut_scifi, 4]
    shifted = qop / (1.0 - eloss * np.abs(qop))
    beyond = np.abs(shifted) * ext.uts_meta[META_P_MIN] > max(ext.uts_meta[META_W_MAX], 1.0)
    groups["ut → scifi: table"] = ut_scifi[~beyond]
    groups["ut → scifi: RK4 fallback"] = ut_scifi[beyond]
    return groups


def base_extrapolator(checkout: Path):
    """The parametrized extrapolator of `checkout`'s pkf (imported as ``pkf_base_<digest>``), its
    record type registered here with its own step, so that this module's kernels run it."""
    import twin

    from pkf.fit.extrapolator import register_extrapolator

    base = twin.load_twin(checkout)
    geometry = twin.submodule(base, "geometry").load_geometry("lhcb-like")
    ext = twin.submodule(base, "params.parameter_set").shipped_parameters(geometry).extrapolator(geometry)
    register_extrapolator(type(ext), twin.submodule(base, "params.transport").parametrized_step)
    return ext


def compare(args, batch, d, geometry, ext, states_in) -> None:
    """--against: every step group and forward-filter stage, base and new alternating."""
    from twin import side_by_side

    base = base_extrapolator(args.against)
    n_nodes = batch.z.size
    arrays = (batch.offsets, batch.z, d["seeds"], d["seed_covs"], batch.n_meas, batch.hx, batch.hy, batch.m,
              batch.sigma)
    rows = {name: (nodes.size, lambda e, nodes=nodes: time_steps(e, nodes, batch.z, states_in))
            for name, nodes in step_groups(ext, batch, geometry, states_in).items() if nodes.size}
    for stage, name in enumerate(STAGES):
        rows[f"forward filter: {name}"] = (n_nodes, lambda e, stage=stage: forward_filter(e, *arrays, stage))
    print(f"parametrized steps, {args.sample}: {batch.n_tracks} tracks, {n_nodes} nodes; ns per step (forward "
          f"filter: per node), CPU, min of {args.repeat} per round, {args.rounds} rounds; base = {args.against}")
    print(f"{'':<36}{'base min':>9}{'median':>8}{'new min':>9}{'median':>8}{'new/base':>9}{'range':>14}")
    results = {"sample": args.sample, "nodes": int(n_nodes), "against": str(args.against), "rounds": args.rounds,
               "repeat": args.repeat, "rows": {}}
    for name, (count, run) in rows.items():
        seconds = side_by_side({"base": lambda run=run: run(base), "new": lambda run=run: run(ext)}, args.rounds,
                               args.repeat)
        per = {side: [1e9 * t / count for t in v] for side, v in seconds.items()}
        ratios = np.array(per["new"]) / np.array(per["base"])
        results["rows"][name] = {"count": int(count), "base": per["base"], "new": per["new"],
                                 "new_over_base_median": float(np.median(ratios)),
                                 "new_over_base_range": [float(ratios.min()), float(ratios.max())]}
        print(f"{name:<36}{min(per['base']):>9.1f}{np.median(per['base']):>8.1f}{min(per['new']):>9.1f}"
              f"{np.median(per['new']):>8.1f}{np.median(ratios):>9.3f}{f'{ratios.min():.3f}–{ratios.max():.3f}':>14}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", choices=("pigun", "minbias"), default="minbias")
    parser.add_argument("--data", type=Path, default=None, help="dataset .npz (default: fit_core's)")
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--against", type=Path, default=None, help="a pkf checkout whose steps to compare with")
    parser.add_argument("--rounds", type=int, default=6, help="alternating rounds of --against")
    args = parser.parse_args()
    batch, d = fit_compare.load_sample(args.sample, args.data)
    geometry = load_geometry("lhcb-like")
    ext, _ = fit_compare._fit_function("parametrized", geometry)
    n_nodes = batch.z.size
    states_in = np.zeros((n_nodes, 5))
    chain_states(ext, batch.offsets, batch.z, d["seeds"], states_in)
    if args.against is not None:
        compare(args, batch, d, geometry, ext, states_in)
        return
    results = {"sample": args.sample, "nodes": int(n_nodes), "steps": {}, "forward_filter": {}}
    print(f"parametrized steps, {args.sample}: {batch.n_tracks} tracks, {n_nodes} nodes")
    print(f"{'step':<28}{'steps':>8}{'ns/step':>10}{'ns/node':>10}")
    for name, nodes in step_groups(ext, batch, geometry, states_in).items():
        if nodes.size == 0:
            continue
        seconds = best_seconds(args.repeat, time_steps, ext, nodes, batch.z, states_in)
        per_step, per_node = 1e9 * seconds / nodes.size, 1e9 * seconds / n_nodes
        results["steps"][name] = {"steps": int(nodes.size), "ns_per_step": per_step, "ns_per_node": per_node}
        print(f"{name:<28}{nodes.size:>8}{per_step:>10.0f}{per_node:>10.1f}")
    print("\nforward filter, ns per node")
    arrays = (batch.offsets, batch.z, d["seeds"], d["seed_covs"], batch.n_meas, batch.hx, batch.hy, batch.m,
              batch.sigma)
    for stage, name in enumerate(STAGES):
        per_node = 1e9 * best_seconds(args.repeat, forward_filter, ext, *arrays, stage) / n_nodes
        results["forward_filter"][name] = per_node
        print(f"{name:<28}{per_node:>10.1f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
