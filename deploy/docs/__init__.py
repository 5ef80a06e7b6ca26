"""``umay docs``: the tables of README.md and docs/*.md, generated from the JSON they come from.

A generated block is marked in the Markdown source::

    <!-- generated: NAME -->
    ...the table, rewritten by ``umay docs``...
    <!-- end generated -->

``NAME`` is one of :data:`.blocks.BLOCKS`, each a pure function of the inputs (the comparison's
rows in ``docs/results/results.json``, the benchmark runs in ``docs/bench/*.json``, the domain
study in ``docs/domains/domains.json``) and of the folder of the document it is written into
(for relative links). ``umay docs`` rewrites every block;
``umay docs --check`` rewrites nothing and names every block that differs from what its JSON
gives. Everything outside the markers is left as written.

Modules: :mod:`.sources` (what the tables come from); the blocks, by source: the comparison's
(:mod:`.results_tables`), the benchmark's (:mod:`.bench_tables`, :mod:`.bench_hosts`,
:mod:`.bench_alternation_tables`, :mod:`.bench_view_tables`; a run's cells:
:mod:`.bench_cells`; the goals and the figures they judge: :mod:`deploy.bench.goals`), the
campaign's, the domain study's and the rest (``*_tables``); :mod:`.blocks` (their names),
:mod:`.documents` (finding and rewriting the blocks in the Markdown), :mod:`.figures`,
:mod:`.cli`. Tables and links in Markdown: :mod:`deploy.markdown`.
"""
