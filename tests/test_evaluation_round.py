"""The evaluation round's rules and its simulation from a results document
(slotv_jax.experiments.people_loop.evaluation_round): the rules follow the answers they are
given and spend no more than their budget, the simulated choice matches an exact binomial
computation, and the command writes its record or refuses bad input in one line."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from slotv_jax.experiments.people_loop import evaluation_round as er

# A Monte Carlo mean is compared with its exact value within this many standard errors.
SE_TOL = 4.0


def _counting(rates):
    """An ``ask`` that answers exactly n · rate (no noise) and counts the answers spent."""
    spent = [0]
    rates = np.asarray(rates, np.float64)

    def ask(idx, n):
        spent[0] += n * idx.shape[1]  # per round: each of the M rounds spends the same
        return n * rates[idx]

    return ask, spent


@pytest.mark.parametrize("rule", [er.uniform_round, er.sequential_halving])
@pytest.mark.parametrize("best", [0, 3, 6])
def test_rules_follow_the_answers(rule, best):
    """Noise-free answers that make candidate ``best`` the most often read correctly: both
    rules keep it, whatever its index, and spend at most the budget per round."""
    rates = np.full(7, 0.3)
    rates[best] = 0.6
    rates[(best + 1) % 7] = 0.5
    ask, spent = _counting(rates)
    chosen = rule(ask, 7, 700, 5, np.random.default_rng(0))
    assert chosen.tolist() == [best] * 5
    assert 0 < spent[0] <= 700


def test_halving_keeps_the_better_half_each_round():
    """Karnin et al.'s schedule on 5 candidates and 600 answers: ⌈log₂ 5⌉ = 3 rounds of
    ⌊600 / (|S| · 3)⌋ answers each for 5, 3 and 2 candidates left."""
    calls = []
    rates = np.array([0.1, 0.5, 0.4, 0.3, 0.2])

    def ask(idx, n):
        calls.append((idx.shape[1], n, sorted(idx[0].tolist())))
        return n * rates[idx]

    assert er.sequential_halving(ask, 5, 600, 1, np.random.default_rng(0)).tolist() == [1]
    assert calls == [(5, 40, [0, 1, 2, 3, 4]), (3, 66, [1, 2, 3]), (2, 100, [1, 2])]


def test_a_budget_too_small_is_refused():
    ask, _ = _counting([0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="budget"):
        er.uniform_round(ask, 3, 2, 1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="budget"):
        er.sequential_halving(ask, 4, 7, 1, np.random.default_rng(0))


def _exact_first(p1: float, p2: float, n: int) -> float:
    """P(the uniform rule keeps candidate 1 of 2): P(X₁ > X₂) + ½ P(X₁ = X₂), X_i ~ B(n, p_i),
    by summing binomial probabilities in float64."""
    pmf = lambda p: [math.comb(n, k) * p**k * (1 - p) ** (n - k) for k in range(n + 1)]  # noqa: E731
    a, b = pmf(p1), pmf(p2)
    return sum(a[i] * (sum(b[:i]) + 0.5 * b[i]) for i in range(n + 1))


def test_expected_gain_matches_an_exact_binomial_computation():
    """Two candidates 0.05 apart in score, 40 answers each: the simulated rounds keep the
    better one as often as the exact binomial sum says, and the expected gain follows."""
    rows = {
        "a": {"score": 0.45, "gain_kept": 0.9},
        "b": {"score": 0.40, "gain_kept": 0.5},
    }
    draws = 20_000
    gain, best_rate = er.expected_gain(rows, "uniform", 80, seed=3, draws=draws)
    p = _exact_first(0.45, 0.40, 40)
    se = math.sqrt(p * (1 - p) / draws)
    assert abs(best_rate - p) < SE_TOL * se
    assert gain == pytest.approx(0.5 + 0.4 * best_rate, abs=1e-12)
    assert 0.55 < p < 0.75  # a real chance of the wrong one: the test can fail


def test_answers_needed_formula():
    """n = (z₀.₉₇₅ + z₀.₈)² · 2 s(1 − s) / (dΔ)², against the quantiles by bisection of erf."""

    def z(q):
        lo, hi = 0.0, 10.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if 0.5 * (1 + math.erf(mid / math.sqrt(2))) < q else (lo, mid)
        return lo

    n = (z(0.975) + z(0.8)) ** 2 * 2 * 0.4 * 0.6 / (0.1 * 0.12) ** 2
    assert er.answers_needed(0.4, 0.12, 0.1) == pytest.approx(n, rel=1e-5)


def _doc():
    """A results document of two populations, two seeds, sizes 250 and 500: three
    candidates, the pool and the pick by plans."""
    pops = []
    for q, shift in (("default", 0.0), ("random:0", 0.05)):
        rows = []
        for sd in (0, 1):
            for a in (250, 500):
                fam = {
                    "mlp": 0.40 + shift,
                    "dragan_fitted": 0.43,
                    "nikolaidis_fitted": 0.38,
                    "pick": 0.42,
                }
                for f, sc in fam.items():
                    rows.append({"family": f, "strategy": "random", "seed": sd, "answers": a,
                                 "score": sc, "gain_kept": (sc - 0.35) / 0.12})  # fmt: skip
                rows.append({"family": "pick_cross", "strategy": "random", "seed": sd,
                             "answers": a, "score": 0.43, "gain_kept": 0.08 / 0.12,
                             "cross_scores": {"mlp": 0.5, "dragan_fitted": 0.6,
                                              "nikolaidis_fitted": 0.1}})  # fmt: skip
        comparison = {"straight": {"score": 0.35}, "oracle": {"score": 0.47}}
        pops.append({"population": q, "rows": rows, "comparison": comparison})
    return {"preset": "quick", "populations": pops}


def test_the_command_writes_its_record(tmp_path):
    src = tmp_path / "people_loop_results.json"
    src.write_text(json.dumps(_doc()))
    out = tmp_path / "out"
    assert er.main([str(src), "--out", str(out), "--draws", "50"]) == 0
    res = json.loads((out / "evaluation_round_quick.json").read_text())
    assert res["budgets"] == [500] and res["fit_size"] == 250
    cell = res["at_budget"]["500"]
    assert set(cell) >= {*er.RULES, "pick", "pick_cross", "best_at_half", "best_at_full"}
    # cross_top2 chooses between dragan_fitted and mlp, never nikolaidis_fitted
    lo = (0.43 - 0.35) / 0.12
    assert cell["cross_top2"]["default"] == pytest.approx(lo, abs=0.2)
    assert cell["best_at_full"]["random:0"] == pytest.approx((0.45 - 0.35) / 0.12)
    assert (out / "evaluation_round_quick.png").stat().st_size > 0
    assert "Does an evaluation round pay?" in (out / "evaluation_round_quick.md").read_text()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["{missing}"], "results: .*missing.json is not a file"),
        (["{doc}", "--draws", "0"], "--draws: expected 1..1000000"),
        (["{bad}"], "not a people loop's results document"),
    ],
)
def test_bad_input_one_line(tmp_path, capsys, args, match):
    doc = tmp_path / "r.json"
    doc.write_text(json.dumps(_doc()))
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    missing = tmp_path / "missing.json"
    argv = [a.format(doc=doc, bad=bad, missing=missing) for a in args]
    argv += ["--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as e:
        er.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(match, err[0])
    assert not (tmp_path / "o").exists()
