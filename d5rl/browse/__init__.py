"""``d5rl browse``: a local web page over the tasks, their datasets, episodes and benchmark runs.

- :mod:`~d5rl.browse.catalog` — every task and dataset, episode series and dataset overviews;
- :mod:`~d5rl.browse.frames` — an episode's camera frames as JPEG strips (from the dataset, its render
  cache, or rendered from stored states on demand and cached under ``$D5RL_HOME/browse-cache``);
- :mod:`~d5rl.browse.runs` — learning curves, tables and videos of ``d5rl bench`` run directories;
- :mod:`~d5rl.browse.server` — the Starlette app, the ``d5rl browse`` command; the page itself is
  ``static/`` (plain JavaScript and Plotly.js, served from the plotly wheel: nothing from the internet).

Install with ``pip install 'd5rl[browse]'``.
"""
