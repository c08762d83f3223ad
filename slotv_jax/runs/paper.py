"""The SLOT-V paper's published Table 1 (Wallkötter et al. 2022, mean and SD over 10 trials),
the reference every accuracy table is compared with.
"""

from __future__ import annotations

from slotv_jax.core.defaults import TEST_SPLITS

# The paper's Table 1: mean (SD) accuracy over 10 trials (Wallkötter et al. 2022).
PAPER = {
    ("dragan", "slotv"): [(0.940, 0.064), (0.938, 0.065), (0.895, 0.083), (0.922, 0.064)],
    ("dragan", "trex"): [(0.795, 0.182), (0.792, 0.180), (0.783, 0.170), (0.749, 0.198)],
    ("effdist", "slotv"): [(1.000, 0.000), (1.000, 0.000), (1.000, 0.000), (0.996, 0.005)],
    ("effdist", "trex"): [(0.796, 0.032), (0.798, 0.034), (0.782, 0.033), (0.772, 0.031)],
    ("fastapp", "slotv"): [(0.973, 0.008), (0.972, 0.008), (0.972, 0.013), (0.954, 0.017)],
    ("fastapp", "trex"): [(0.869, 0.034), (0.866, 0.034), (0.879, 0.024), (0.860, 0.006)],
    ("nikolaidis", "slotv"): [(0.911, 0.029), (0.910, 0.031), (0.875, 0.054), (0.893, 0.041)],
    ("nikolaidis", "trex"): [(0.845, 0.033), (0.844, 0.034), (0.841, 0.039), (0.796, 0.040)],
}
PAPER_TABLE = {
    (lab, meth, split): PAPER[(lab, meth)][i]
    for (lab, meth) in PAPER
    for i, split in enumerate(TEST_SPLITS)
}
