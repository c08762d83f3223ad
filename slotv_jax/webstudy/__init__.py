"""Running a legibility study in the browser.

- :mod:`.stimuli`: stimulus sets and their rounds on disk (``manifest.json``, clips);
  :mod:`.make_stimuli` renders them from datasets, study files and plans;
- :mod:`.design`: the kinds of trials and what a participant is assigned;
- :mod:`.database`: every answer in SQLite, committed before the page moves on;
- :mod:`.service` (the study's rules) and :mod:`.server` (the thin Starlette routes),
  ``static/`` (the participant page); :mod:`.limits`: what one client may hold of the
  server (timeouts, a bound on connections);
- :mod:`.client`: participants over HTTP (simulated people answering the real server);
- :mod:`.export`: the answers as the tables :mod:`slotv_jax.answers.tables` reads;
- :mod:`.web_cli`: the ``stimuli``, ``serve``, ``simulate`` and ``export`` commands.

It imports :mod:`slotv_jax.answers` (study files as stimuli) and the library rooms below it;
choosing what to ask (:mod:`slotv_jax.asking`) is not its business.
"""
