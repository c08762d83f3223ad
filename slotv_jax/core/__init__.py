"""The ground floor: atomic file writes (:mod:`.fileio`), input checks (:mod:`.validation`) and the
XLA CPU settings (:mod:`.xla`). Imports nothing else of slotv_jax.
"""

__version__ = "0.1.0"  # the package version (pyproject.toml says the same)
