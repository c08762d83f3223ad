"""Benchmark: SLOT-V and T-REX training steps, against the device's matmul peak.

    python -m slotv_jax.benchmarks.training              # paper sizes; CPU: short windows
    python -m slotv_jax.benchmarks.training --device-run # GPU: long windows, variants
    python -m slotv_jax.benchmarks.training --preset quick --steps 250 --repeats 11 \
        --dtypes float32 --variant-methods slotv,trex    # the CPU's quick sizes, variants

What is timed is the real compiled training loop (:meth:`slotv_jax.training.trainer.Trainer.run`):
one call runs one epoch, a ``lax.scan`` of ``--steps`` updates over synthetic data held
on the device (no host sync per update, the state donated). Per (method, dtype):

- trajectories/s: SLOT-V trajectories per second; T-REX pairs per second × 2;
- achieved FLOP/s: analytic matmul FLOPs per update over its time. Forward FLOPs per
  trajectory and goal are 2·(3·H1/G + Σ_l H_l·H_{l+1} · T + H_L · T) (the goal-relative
  layer counted as a (T, 3)×(3, H1) and a (G, 3)×(3, H1) product per trajectory; it is
  computed elementwise from p − g, and negligible either way); an update costs
  ≈ 3× its forward FLOPs (backward: gradients w.r.t. activations and weights). The
  synthetic scenes have 2, 3, 5 or 6 goals, like the training split; as in training the
  two slots no scene uses are cut (``--all-slots`` keeps all 8), and the remaining padded
  slots are computed and counted (the loop has fixed shapes);
- the matmul peak of the same device and dtype, measured in the same run: an N×N×N
  ``jnp.dot`` (N = 8192 on GPUs, 2048 on CPUs), median of repeated calls.

Also reported: forward-only evaluation throughput (:ref:`concepts-accuracy` accuracy, chunked), and
for the ``--variant-methods`` (default with ``--device-run``: slotv) the variants of the
update, each timed round-robin with the default in the same process (the order rotates
every round): the default again (the run's noise floor), the other first-layer gradients
(``backward``; "autodiff" is the simplest form) and, where SLOT-V updates are packed
(CPUs), the update without packing and the simplest form of all (autodiff, not packed).
``--preset quick`` times the quick preset's network and batch sizes (what CPUs run).

The data are synthetic: no dataset needs to be generated.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import gzip
import itertools
import json
import pathlib
import platform
import statistics
import sys
import time
from collections import defaultdict

import flax
import jax
import jax.numpy as jnp
import jaxlib
import numpy as np
import optax

import slotv_jax  # applies the XLA CPU setting before JAX starts
from slotv_jax.core import cli, fileio
from slotv_jax.observers.models import BACKWARDS
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train
from slotv_jax.training.trainer import default_backward, packs_updates

T = 100
G = 8


def variants(backward: str, method: str, packed: bool) -> list[tuple[str, dict]]:
    """The default again (the noise floor of the run), the other first-layer gradients
    (``Trainer.backward``), and on CPUs, for SLOT-V, the update without packing and the
    simplest form of all (autodiff, not packed)."""
    if backward == "auto":
        backward = default_backward(jax.default_backend(), method)
    out = [("default, again (the noise floor)", {"backward": backward})]
    out += [(f"backward={b}", {"backward": b}) for b in BACKWARDS if b != backward]
    if packed and method == "slotv":
        out += [("not packed", {"backward": backward, "pairs": 0})]
        out += [("simplest: autodiff, not packed", {"backward": "autodiff", "pairs": 0})]
    return out


def forward_flops(hidden: tuple[int, ...], rows_per_traj: int, goals_per_traj: int) -> float:
    """Matmul FLOPs of one forward pass over one trajectory (``rows_per_traj`` = T · goals)."""
    f = 2 * 3 * hidden[0] * (T + goals_per_traj)  # W1 p_t and W1 g_k
    for a, b in itertools.pairwise(hidden):
        f += 2 * a * b * rows_per_traj
    f += 2 * hidden[-1] * goals_per_traj  # readout, once per goal (after the reduction over t)
    return float(f)


def update_flops(cfg, goal_slots: int = G) -> tuple[float, int]:
    """(FLOPs per update ≈ 3 × forward, trajectories per update) with ``goal_slots`` slots."""
    if cfg.method == "slotv":
        per = forward_flops(cfg.hidden, T * goal_slots, goal_slots)
        return 3.0 * per * cfg.batch_size, cfg.batch_size
    per_pair = 2 * forward_flops(cfg.hidden, T, 1)  # two trajectories, one goal each
    return 3.0 * per_pair * cfg.batch_size, 2 * cfg.batch_size


def synthetic_data(n: int, seed: int = 0, trim: bool = True):
    """Random but valid trajectories, scenes (2, 3, 5 or 6 goals, as the training split) and
    label distributions (on the host); ``trim`` cuts the two slots no scene uses, as
    :func:`slotv_jax.training.trainer.train_trials` does."""

    rng = np.random.default_rng(seed)
    counts = rng.choice([2, 3, 5, 6], n)
    mask = np.arange(G)[None] < counts[:, None]
    goals = np.zeros((n, G, 3), np.float32)
    goals[..., 0] = rng.uniform(0.3, 0.7, (n, G))
    goals[..., 1] = rng.uniform(-0.45, 0.45, (n, G))
    goals[..., 2] = 0.025
    goals = np.where(mask[..., None], goals, 0.0).astype(np.float32)
    t = np.linspace(0, 1, T)[None, :, None]
    start = np.array([0.3069, 0.0, 0.4869])
    end = goals[np.arange(n), rng.integers(0, counts)]
    bend = rng.normal(0, 0.1, (n, 1, 3)) * np.sin(np.pi * t)
    xyz = ((1 - t) * start + t * end[:, None] + bend).astype(np.float32)
    logits = np.where(mask, rng.normal(size=(n, G)), -np.inf)
    y = np.exp(logits - logits.max(-1, keepdims=True))
    y = (y / y.sum(-1, keepdims=True)).astype(np.float32)
    data = train.TrainData(xyz, goals, mask, y)
    return train.trim_goals(data) if trim else data


def paper_pair_capacity(trials: int = 10, preset: str = "paper") -> int:
    """The packed SLOT-V pairs per update of a ``preset`` run of ``trials`` trials
    (seeds 0..trials−1, the preset's epochs) on synthetic training trajectories (100,000
    for the paper preset, the quick preset's ``train_size``)."""

    cfg = train_config.PRESETS[preset]("slotv")
    trainer = train.make_train(cfg, progress=False)
    keys = jax.vmap(train.Trainer.state_key)(train.trial_keys(trials))
    n = cfg.train_size or 100_000
    return trainer.pair_capacity(keys, synthetic_data(n).goal_mask, range(cfg.epochs))


def _median_time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def matmul_peak(dtype: str, n: int, repeats: int) -> float:
    """FLOP/s of a jitted n×n×n ``jnp.dot`` in ``dtype`` on random data (median of calls)."""

    dt = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}[dtype]
    ka, kb = jax.random.split(jax.random.key(0))
    a = jax.random.normal(ka, (n, n), dt)
    b = jax.random.normal(kb, (n, n), dt)
    dot = jax.jit(jnp.dot)
    jax.block_until_ready(dot(a, b))
    t = _median_time(lambda: jax.block_until_ready(dot(a, b)), max(repeats, 10))
    return 2.0 * n**3 / t


@dataclasses.dataclass
class Row:
    name: str
    dtype: str
    batch: int
    hidden: tuple[int, ...]
    step_ms: float
    traj_per_s: float
    flops_per_s: float
    peak: float
    compile_s: float

    @property
    def frac(self) -> float:
        return self.flops_per_s / self.peak


def build_train(
    method: str,
    dtype: str,
    steps: int,
    *,
    backward: str = "auto",
    trim: bool = True,
    trials: int = 1,
    pairs: int = 0,
    preset: str = "paper",
):
    """Compile one timed epoch of ``steps`` updates: (``once()``, which runs it, FLOPs per
    update, compile seconds, cfg, goal slots per trajectory computed, compiled). With
    ``trials`` > 1, that many vmapped trials per call (FLOPs of all of them together).
    ``pairs`` > 0 packs SLOT-V updates to that many (trajectory, goal) pairs
    (:func:`slotv_jax.train.slotv_loss_packed`)."""

    cfg = train_config.PRESETS[preset](method, compute_dtype=dtype, epochs=1, log_every=steps)
    cfg = dataclasses.replace(cfg, train_size=None)
    n = steps * cfg.batch_size
    pairs = pairs if method == "slotv" else 0
    trainer = train.make_train(cfg, progress=False, backward=backward, packed_pairs=pairs)
    data = trainer.replicate(synthetic_data(n, trim=trim))
    slots = pairs / cfg.batch_size if pairs else data.goals.shape[1]
    run = functools.partial(trainer.run, epochs=1)
    if trials > 1:
        keys = jax.random.split(jax.random.key(0), trials)
        state = trainer.replicate(jax.vmap(trainer.init)(keys))
        run = jax.vmap(run, in_axes=(0, None))
    else:
        state = trainer.replicate(trainer.init(jax.random.key(0)))
    epoch = jax.jit(run, donate_argnums=0)
    t0 = time.perf_counter()
    compiled = epoch.lower(state, data).compile()
    compile_s = time.perf_counter() - t0
    holder = [compiled(state, data)[0]]  # warm-up

    def once():
        holder[0], m = compiled(holder[0], data)
        jax.block_until_ready(m)

    flops, _ = update_flops(cfg, slots)
    return once, flops * trials, compile_s, cfg, slots, compiled


def interleaved(fns: list, repeats: int) -> list[float]:
    """Median seconds of each of ``fns``, called round-robin ``repeats`` times, each round
    starting one further along (so that a change of load on a shared machine, and the
    position in the round, hit every variant alike)."""
    ts: list[list[float]] = [[] for _ in fns]
    for r in range(repeats):
        for i in range(len(fns)):
            j = (i + r) % len(fns)
            t0 = time.perf_counter()
            fns[j]()
            ts[j].append(time.perf_counter() - t0)
    return [statistics.median(t) for t in ts]


def bench_train(
    method: str,
    dtype: str,
    steps: int,
    repeats: int,
    *,
    profile: str | None = None,
    **kw,
) -> tuple[float, float, float, object, float]:
    """(seconds per update, FLOPs per update, compile seconds, cfg, goal slots per
    trajectory computed) of the loop built by :func:`build_train` (``kw``)."""

    once, flops, compile_s, cfg, slots, compiled = build_train(method, dtype, steps, **kw)
    t = _median_time(once, repeats) / steps
    if profile:
        d = pathlib.Path(profile)
        d.mkdir(parents=True, exist_ok=True)
        tag = f"{method}_{dtype}_" + "_".join(f"{k}{v}" for k, v in sorted(kw.items()))
        (d / f"{tag}.hlo.txt").write_text(compiled.as_text())
        with jax.profiler.trace(str(d / tag), create_perfetto_trace=True):
            for _ in range(2):
                once()
        kernel_summary(d / tag, steps * 2)
    return t, flops, compile_s, cfg, slots


def kernel_summary(trace_dir, updates: int, top: int = 25) -> None:
    """Print the device kernels of a profiler trace by total time (per update)."""

    files = sorted(pathlib.Path(trace_dir).rglob("*.trace.json.gz"))
    if not files:
        print(f"    (no perfetto trace under {trace_dir})")
        return
    doc = json.loads(gzip.open(files[-1]).read())
    events = doc["traceEvents"] if isinstance(doc, dict) else doc
    names = {e["pid"]: e["args"]["name"] for e in events
             if e.get("ph") == "M" and e.get("name") == "process_name"}  # fmt: skip
    dev = {p for p, n in names.items() if "GPU" in n or "gpu" in n or "TPU" in n}
    tot: dict[str, float] = defaultdict(float)
    cnt: dict[str, int] = defaultdict(int)
    for e in events:
        if e.get("ph") == "X" and (not dev or e.get("pid") in dev):
            tot[e["name"]] += e.get("dur", 0.0)
            cnt[e["name"]] += 1
    total = sum(tot.values())
    print(f"    device time in trace: {total / updates:.1f} µs/update over {len(tot)} kernels "
          f"(pids {sorted(names[p] for p in dev) if dev else 'all'})")  # fmt: skip
    for name, us in sorted(tot.items(), key=lambda kv: -kv[1])[:top]:
        print(f"    {us / updates:9.1f} µs/update {100 * us / total:5.1f}%  "
              f"x{cnt[name] / updates:.2f}  {name[:110]}")  # fmt: skip


def build_eval(method: str, dtype: str, n: int, trim: bool = True, *, preset: str = "paper"):
    """Compile chunked :ref:`concepts-accuracy` accuracy over ``n`` trajectories: (``once()``,
    forward FLOPs per call, compile seconds, cfg)."""

    cfg = train_config.PRESETS[preset](method, compute_dtype=dtype)
    trainer = train.make_train(cfg, progress=False)
    params = trainer.replicate(trainer.init(jax.random.key(0)).params)
    data = synthetic_data(n, seed=1, trim=trim)
    ev = trainer.replicate(trainer.eval_data(data, size=n))
    f = jax.jit(trainer.accuracy)
    t0 = time.perf_counter()
    compiled = f.lower(params, ev).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(params, ev))
    g = data.goals.shape[1]
    fl = forward_flops(cfg.hidden, T * g, g) * n
    return (lambda: jax.block_until_ready(compiled(params, ev))), fl, compile_s, cfg


def bench_eval(
    method: str, dtype: str, n: int, repeats: int, trim: bool = True, **kw
) -> tuple[float, float, float]:
    """(trajectories/s, FLOP/s, compile s) of chunked :ref:`concepts-accuracy` accuracy
    (:func:`build_eval`)."""
    once, fl, compile_s, _ = build_eval(method, dtype, n, trim, **kw)
    t = _median_time(once, repeats)
    return n / t, fl / t, compile_s


def environment() -> dict:

    devs = jax.devices()
    return {
        "date": datetime.date.today().isoformat(),
        "device": f"{len(devs)} × {devs[0].device_kind} ({devs[0].platform})",
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "flax": flax.__version__,
        "optax": optax.__version__,
        "python": platform.python_version(),
        "host": platform.machine(),
        "xla_flags": slotv_jax.XLA_CONFIG.xla_flags,
    }


@cli.command
def main(argv=None) -> int:
    ap = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.training")
    ap.add_argument("--device-run", action="store_true", help="accelerator settings + variants")
    ap.add_argument("--preset", default="paper", choices=("paper", "quick"), help="model sizes")
    ap.add_argument("--eval-size", type=int, default=None, help="trajectories per eval call")
    ap.add_argument("--steps", type=int, default=None, help="updates per timed epoch")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--dtypes", default="float32,bfloat16")
    ap.add_argument("--methods", default="slotv,trex")
    ap.add_argument("--no-eval", action="store_true")
    ap.add_argument("--backward", default="auto", help="first-layer gradient implementation")
    ap.add_argument(
        "--variant-methods", default=None,
        help="methods to also time with the other implementations (default: slotv with "
        "--device-run, none otherwise)",
    )  # fmt: skip
    ap.add_argument(
        "--all-slots", action="store_true",
        help="compute all 8 goal slots (default: as training does, cut the 2 unused ones and "
        "pack SLOT-V updates to the real pairs)",
    )  # fmt: skip
    ap.add_argument(
        "--dense", action="store_true",
        help="6 goal slots, SLOT-V updates not packed (the GPU default)",
    )  # fmt: skip
    ap.add_argument(
        "--variants", default="",
        help="comma-separated substrings: time only the variants whose label has one",
    )  # fmt: skip
    ap.add_argument(
        "--vmap-trials", default="",
        help="comma-separated trial counts to also time vmapped together (e.g. 2,4)",
    )  # fmt: skip
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    ap.add_argument("--profile", default=None, help="dir: HLO + kernel profile of slotv train")
    args = ap.parse_args(argv)
    if args.json:  # checked before the benchmark; the file is regenerated
        json_path = pathlib.Path(args.json)
        fileio.check_output_files(json_path.parent, [json_path.name], what="--json")
    if args.profile:  # new files are added to the folder
        fileio.check_output_files(args.profile, [], what="--profile")

    gpu = jax.default_backend() != "cpu"
    if args.variant_methods is None:
        args.variant_methods = "slotv" if args.device_run else ""
    steps = args.steps or (400 if gpu else 3)
    repeats = args.repeats or (5 if gpu else 2)
    n_peak = 8192 if gpu else 2048
    n_eval = args.eval_size or (16384 if gpu else 64)
    env = environment()
    print(slotv_jax.XLA_CONFIG.summary())
    print(json.dumps(env), flush=True)
    print(f"steps per timed epoch {steps}, repeats {repeats}, peak matmul {n_peak}³", flush=True)

    pairs = 0
    if packs_updates(jax.default_backend()) and not (args.all_slots or args.dense):
        pairs = paper_pair_capacity(10 if args.preset == "paper" else 2, args.preset)
    if pairs:
        print(f"SLOT-V updates packed to {pairs} real (trajectory, goal) pairs of the 32 × 6 "
              f"slots (the most in any batch of a {args.preset} run)", flush=True)  # fmt: skip
    rows: list[Row] = []
    extra: list[dict] = []
    for dtype in args.dtypes.split(","):
        peak = matmul_peak(dtype, n_peak, repeats)
        print(f"[{dtype}] matmul peak {peak / 1e12:.2f} TFLOP/s", flush=True)
        for method in args.methods.split(","):
            trim = not args.all_slots
            t, fl, cs, cfg, slots = bench_train(
                method, dtype, steps, repeats, backward=args.backward, profile=args.profile,
                trim=trim, pairs=pairs, preset=args.preset,
            )  # fmt: skip
            _, traj = update_flops(cfg, slots)
            slot_note = ""
            if method == "slotv":
                slot_note = f", {pairs} pairs" if pairs else f", {slots} goal slots"
            bw = default_backward(jax.default_backend(), method)
            bw = bw if args.backward == "auto" else args.backward
            name = f"{method} train ({bw}{slot_note})"
            row = Row(name, dtype, cfg.batch_size, cfg.hidden, t * 1e3,
                      traj / t, fl / t, peak, cs)  # fmt: skip
            rows.append(row)
            print(f"  {row.name}: {row.step_ms:.3f} ms/update, {row.traj_per_s:,.0f} traj/s, "
                  f"{row.flops_per_s / 1e12:.2f} TFLOP/s = {100 * row.frac:.1f}% of peak "
                  f"(compile {cs:.1f} s)", flush=True)  # fmt: skip
            if method in args.variant_methods.split(","):
                wanted = [w for w in args.variants.split(",") if w]
                chosen = [(label, {"pairs": pairs, **kw}) for label, kw in
                          variants(args.backward, method, bool(pairs))
                          if not wanted or any(w in label for w in wanted)]  # fmt: skip
                base = {"backward": args.backward, "trim": trim, "pairs": pairs,
                        "preset": args.preset}  # fmt: skip
                built = [build_train(method, dtype, steps, **base)]
                built += [build_train(method, dtype, steps, trim=trim, preset=args.preset, **kw)
                          for _, kw in chosen]  # fmt: skip
                times = interleaved([b[0] for b in built], repeats)
                t0 = times[0] / steps
                print(f"    interleaved, {repeats} rounds: default {t0 * 1e3:.3f} ms/update",
                      flush=True)  # fmt: skip
                for (label, _), b, tv in zip(chosen, built[1:], times[1:], strict=True):
                    tv /= steps
                    flv = b[1]
                    v = {"method": method, "variant": label, "dtype": dtype, "step_ms": tv * 1e3,
                         "default_ms": t0 * 1e3, "ratio": tv / t0, "traj_per_s": traj / tv,
                         "frac_peak": flv / tv / peak}  # fmt: skip
                    extra.append(v)
                    print(f"    variant {label}: {tv * 1e3:.3f} ms/update ({tv / t0:.3f} × "
                          f"default), {traj / tv:,.0f} traj/s, {100 * flv / tv / peak:.1f}% of "
                          "peak", flush=True)  # fmt: skip
            for k in [int(x) for x in args.vmap_trials.split(",") if x]:
                tv, flv, *_ = bench_train(
                    method, dtype, steps, repeats, backward=args.backward, trim=trim, trials=k,
                    pairs=pairs, preset=args.preset,
                )  # fmt: skip
                v = {"method": method, "variant": f"{k} vmapped trials", "dtype": dtype,
                     "step_ms": tv * 1e3 / k, "traj_per_s": k * traj / tv,
                     "frac_peak": flv / tv / peak}  # fmt: skip
                extra.append(v)
                print(f"    {k} vmapped trials: {tv * 1e3 / k:.3f} ms/update per trial, "
                      f"{k * traj / tv:,.0f} traj/s, {100 * flv / tv / peak:.1f}% of peak",
                      flush=True)  # fmt: skip
            if not args.no_eval:
                tps, fps, ecs = bench_eval(method, dtype, n_eval, repeats, trim, preset=args.preset)
                rows.append(Row(f"{method} eval", dtype, n_eval, cfg.hidden, 1e3 * n_eval / tps,
                                tps, fps, peak, ecs))  # fmt: skip
                print(f"  {method} eval: {tps:,.0f} traj/s, {fps / 1e12:.2f} TFLOP/s = "
                      f"{100 * fps / peak:.1f}% of peak", flush=True)  # fmt: skip

    print()
    print(f"device: {env['device']}; jax {env['jax']}, flax {env['flax']}, {env['date']}")
    print(
        "| what | dtype | batch | hidden | ms/call | trajectories/s | TFLOP/s | % of matmul peak |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r.name} | {r.dtype} | {r.batch} | {'/'.join(map(str, r.hidden))} | "
              f"{r.step_ms:.3f} | {r.traj_per_s:,.0f} | {r.flops_per_s / 1e12:.3f} | "
              f"{100 * r.frac:.1f}% (peak {r.peak / 1e12:.2f}) |")  # fmt: skip
    if args.json:
        doc = {"environment": env, "rows": [dataclasses.asdict(r) for r in rows], "variants": extra}
        fileio.write_text(args.json, json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
