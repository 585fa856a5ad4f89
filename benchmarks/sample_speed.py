"""Effective samples per second of emcee on strauss-fit's posterior: the jitted, vectorised
JAX log-probability against a plain NumPy log-probability, in one run.

Run from the repository root::

    .venv/bin/python benchmarks/sample_speed.py [--size 32] [--steps 1000] [--walkers 32,64,128] [--json PATH]

What it does (all in one process, on this machine):

1. Renders a synthetic target (``--size`` square, two directional lights and ambient light
   over black, the local model; material C = (0.7, 0.4, 0.2), s = 0.6, m = 0.4) with
   Gaussian noise σ = 0.01, and fits colour, smoothness and metalness (5 parameters).
2. Builds two log-posteriors of the *same* model (Gaussian likelihood at the known σ, the
   uniform prior of :mod:`strauss_fit.inference.posterior`):

   - **JAX**: :class:`strauss_fit.inference.posterior.LogPosterior`, one jitted ``vmap`` over the
     walkers, called by emcee with ``vectorize=True`` (what ``strauss-fit sample`` runs);
   - **NumPy**: ``benchmarks/numpy_reference.shade_numpy`` (plain NumPy float64,
     vectorised over pixels, the sphere's normals computed once), one call per walker,
     emcee's default ``vectorize=False``.

   They must agree to 1e-9 (relative) at a few points before anything is timed.
3. For each walker count, runs emcee with each for ``--steps`` steps from the same walkers
   and the same random seed (in-memory backend: storage is not what is compared), timing
   the whole ``run_mcmc``; the JAX function is compiled and warmed first (its compile
   time is printed apart). For the first walker count a third row runs the JAX version
   through ``strauss_fit.inference.sampler.run_sampler`` with the HDF5 chain file, to show what
   storage and the convergence checks cost.
4. Effective samples = walkers × (steps − burn-in) / τ̂ for the worst-mixing parameter
   (τ̂ emcee's integrated autocorrelation time, burn-in 2 τ̂); the speed-up is the ratio of
   effective samples per second at the same walker count. The two chains are the same
   (same proposals, the same accept decisions up to float rounding: checked), so this is
   also the ratio of wall times. Target: at least 20×.

Where the time goes (JAX, 32 walkers, 32 × 32): each emcee step makes two calls of 16
walkers; a call costs a fixed ~0.1 ms (dispatch and XLA:CPU's runtime) plus ~20 ns per
walker and pixel, and emcee's own Python per step (the stretch move, copying the random
state) costs ~0.3–0.5 ms — as much as the model. NumPy spends ~0.4 ms per walker (it also
recomputes the angles and F, G that the JAX side precomputed once). So the speed-up grows
with the number of walkers, which a vectorised log-probability makes cheap.

Prints a table and writes JSON (default ``benchmarks/results/sample_speed.json``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import emcee  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402
from bench_common import key_and_fill_scene, legacy_options, machine, write_json  # noqa: E402
from numpy_reference import shade_numpy, sphere_normals  # noqa: E402

import strauss_fit as sf  # noqa: E402
from strauss_fit import Target, fit  # noqa: E402
from strauss_fit.inference.posterior import LogPosterior, default_prior  # noqa: E402
from strauss_fit.inference.sampler import (  # noqa: E402
    SampleSettings,
    autocorrelation_times,
    burn_in,
    initial_walkers,
    run_sampler,
)
from strauss_fit.stats.laplace import laplace_covariance  # noqa: E402

#: The material of the scene (key_and_fill.toml, local model only).
SCENE_MATERIAL = dict(color=[0.5, 0.5, 0.5], smoothness=0.5, metalness=0.2)
TRUTH = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)
SIGMA = 0.01


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=32, help="image width and height in pixels (default 32)")
    parser.add_argument("--steps", type=int, default=1000, help="emcee steps per run (default 1000)")
    parser.add_argument(
        "--walkers",
        type=lambda t: [int(v) for v in t.split(",")],
        default=[32, 64, 128],
        help="walker counts, comma-separated (default 32,64,128; 32 is what 'sample' uses for 5 parameters)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--json",
        type=Path,
        default=HERE / "results" / "sample_speed.json",
        help="where to write the results (default benchmarks/results/sample_speed.json)",
    )
    return parser.parse_args(argv)


class NumpyLogPosterior:
    """The same log-posterior in plain NumPy, one walker per call."""

    def __init__(self, scene, used: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray, sigma: float):
        normals, mask = sphere_normals(scene.camera.width, scene.camera.height)
        # the usable sphere pixels, in the same (row-major) order as the fit's
        keep = used[mask]
        self.normals = normals[keep]
        self.target = target[used]
        lights = scene.lights
        self.directions = np.asarray(lights.directional.direction, dtype=np.float64)
        self.intensities = np.asarray(lights.directional.intensity, dtype=np.float64)
        self.light_colors = np.asarray(lights.directional.color, dtype=np.float64)
        self.ambient = float(np.asarray(lights.ambient))
        self.lower, self.upper = lower, upper
        self.scale = -0.5 / sigma**2

    def __call__(self, x: np.ndarray) -> float:
        if np.any(x < self.lower) or np.any(x > self.upper):
            return -np.inf
        radiance = shade_numpy(
            self.normals, x[:3], x[3], x[4], 0.0, self.directions, self.intensities, self.light_colors, self.ambient
        )
        r = radiance - self.target
        return self.scale * float(np.sum(r * r))


def effective(chain: np.ndarray) -> dict:
    steps, walkers, _ = chain.shape
    tau = autocorrelation_times(chain)
    burn = burn_in(tau, steps)
    ess = walkers * (steps - burn) / tau
    return {
        "tau": tau.tolist(),
        "tau_max": float(tau.max()),
        "burn_in": burn,
        "ess_min": float(ess.min()),
        "ess": ess.tolist(),
    }


def run_emcee(log_prob, vectorize: bool, start: np.ndarray, steps: int, seed: int) -> tuple[np.ndarray, float, float]:
    sampler = emcee.EnsembleSampler(start.shape[0], start.shape[1], log_prob, vectorize=vectorize)
    state = emcee.State(start, random_state=np.random.RandomState(seed).get_state())
    t0 = time.perf_counter()
    sampler.run_mcmc(state, steps)
    wall = time.perf_counter() - t0
    return sampler.get_chain(), wall, float(np.mean(sampler.acceptance_fraction))


def machine_info() -> dict:
    """:func:`bench_common.machine` (printed) with the versions of NumPy and emcee and the device."""
    return {
        **machine(),
        "numpy": np.__version__,
        "emcee": emcee.__version__,
        "jax_device": str(jax.devices()[0]),
        "load_average_before": os.getloadavg(),
    }


def main(args: argparse.Namespace) -> dict:
    info = machine_info()
    scene = key_and_fill_scene(args.size, material=SCENE_MATERIAL, depth=1)
    image, hit = sf.render(scene, sf.Material(**TRUTH))
    pixels = np.asarray(image) + SIGMA * np.random.default_rng(args.seed).normal(size=np.shape(image))
    target = Target(pixels, np.ones(np.shape(hit), bool), "synthetic", "linear", 0, 0)
    result = fit(scene, target, legacy_options(free=("color", "smoothness", "metalness")))
    problem, x_hat = result.problem, np.asarray(result.x)
    prior = default_prior(problem.layout, x_hat)
    jax_lp = LogPosterior(problem, prior, SIGMA)
    used = np.asarray(hit) & target.usable
    numpy_lp = NumpyLogPosterior(scene, used, pixels, prior.lower, prior.upper, SIGMA)
    print(
        f"emcee on the Strauss posterior: {args.size}x{args.size} image, {int(used.sum())} pixels, "
        f"{x_hat.size} parameters, {args.steps} steps with {', '.join(map(str, args.walkers))} walkers"
    )

    covariance = laplace_covariance(problem, x_hat, SIGMA)
    start = initial_walkers(x_hat, covariance, prior, max(args.walkers), np.random.default_rng(args.seed), jax_lp)
    # the two log-probabilities must be the same function
    probe = np.vstack([x_hat, start[:4]])
    a, b = jax_lp(probe), np.array([numpy_lp(x) for x in probe])
    agreement = float(np.max(np.abs(a - b) / np.abs(b)))
    assert agreement < 1e-9, f"JAX and NumPy log-probabilities differ by {agreement:.1e} (relative)"
    print(f"self-check: JAX vs NumPy log-probability, max relative difference {agreement:.1e} (< 1e-9)")

    rows, compile_s, identical = [], {}, {}
    for walkers in args.walkers:
        begin = initial_walkers(x_hat, covariance, prior, walkers, np.random.default_rng(args.seed), jax_lp)
        t0 = time.perf_counter()  # compile and warm at both batch sizes emcee uses (all, half)
        jax_lp(begin)
        jax_lp(begin[: walkers // 2])
        compile_s[walkers] = time.perf_counter() - t0
        chain_np, wall, acc = run_emcee(numpy_lp, False, begin, args.steps, args.seed)
        rows.append(
            {
                "walkers": walkers,
                "name": "NumPy log-prob, one walker per call",
                "wall_s": wall,
                "acceptance": acc,
                **effective(chain_np),
            }
        )
        chain, wall, acc = run_emcee(jax_lp, True, begin, args.steps, args.seed)
        rows.append(
            {
                "walkers": walkers,
                "name": "JAX log-prob, jit + vmap, vectorize=True",
                "wall_s": wall,
                "acceptance": acc,
                **effective(chain),
            }
        )
        identical[walkers] = bool(np.allclose(chain, chain_np, rtol=0, atol=1e-9))
        if walkers == args.walkers[0]:
            with tempfile.TemporaryDirectory() as folder:
                t0 = time.perf_counter()
                run = run_sampler(
                    jax_lp,
                    Path(folder) / "chain.h5",
                    start=begin,
                    metadata={},
                    settings=SampleSettings(max_steps=args.steps, min_tau_multiple=1e9, seed=args.seed),
                )
                wall = time.perf_counter() - t0
            rows.append(
                {
                    "walkers": walkers,
                    "name": "JAX, strauss-fit run_sampler + HDF5 chain file",
                    "wall_s": wall,
                    "acceptance": run.diagnostics.acceptance_mean,
                    **effective(run.chain),
                }
            )
    for r in rows:
        baseline = next(b for b in rows if b["walkers"] == r["walkers"] and b["name"].startswith("NumPy"))
        r["steps_per_s"] = args.steps / r["wall_s"]
        r["log_probs_per_s"] = args.steps * r["walkers"] / r["wall_s"]
        r["ess_per_s"] = r["ess_min"] / r["wall_s"]
        r["speedup_vs_numpy"] = r["ess_per_s"] / (baseline["ess_min"] / baseline["wall_s"])

    header = (
        f"{'walkers':>7}  {'run':<48} {'wall s':>8} {'steps/s':>8} {'logp/s':>8} {'tau max':>7} "
        f"{'min ESS':>8} {'ESS/s':>8} {'x NumPy':>8}"
    )
    print()
    print(header)
    print("-" * len(header))
    for r in rows:
        print(
            f"{r['walkers']:>7}  {r['name']:<48} {r['wall_s']:>8.2f} {r['steps_per_s']:>8.0f} "
            f"{r['log_probs_per_s']:>8.0f} "
            f"{r['tau_max']:>7.1f} {r['ess_min']:>8.0f} {r['ess_per_s']:>8.1f} {r['speedup_vs_numpy']:>8.1f}"
        )
    jax_rows = {r["walkers"]: r for r in rows if r["name"].startswith("JAX log-prob")}
    print(
        "\nJAX compile + warm-up per walker count (not in the table): "
        + ", ".join(f"{w}: {t:.2f} s" for w, t in compile_s.items())
        + f". JAX and NumPy chains identical to 1e-9: {identical}."
    )
    for walkers, r in jax_rows.items():
        print(
            f"effective samples per second, JAX / NumPy, {walkers} walkers: {r['speedup_vs_numpy']:.1f}x "
            "(target: >= 20x)"
        )
    info["load_average_after"] = os.getloadavg()
    out = {
        "benchmark": "sample_speed",
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": info,
        "size": args.size,
        "pixels": int(used.sum()),
        "parameters": int(x_hat.size),
        "walkers": args.walkers,
        "steps": args.steps,
        "sigma": SIGMA,
        "self_check_max_relative_difference": agreement,
        "jax_compile_s": {str(k): v for k, v in compile_s.items()},
        "chains_identical": {str(k): v for k, v in identical.items()},
        "rows": rows,
        "speedup_ess_per_s": {str(w): r["speedup_vs_numpy"] for w, r in jax_rows.items()},
    }
    write_json(args.json, out)
    return out


if __name__ == "__main__":
    with sf.float64():  # all of it in float64 (importing strauss_fit no longer switches it on)
        main(parse_args())
