"""The command line that trains one observer: ``python -m slotv_jax.train``
(:ref:`concepts-public-names`)."""
