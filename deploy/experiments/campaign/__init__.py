"""``umay campaign``: every strategy from random starts, and why each failure failed.

The suite's starts were chosen by hand; a campaign draws them from a distribution kept in the
repository (``deploy/campaigns/random_starts.toml``, documented there): targets anywhere on
the table within the image at any yaw, the hand up to 15 cm from its goal and turned up to 45°
about the optical axis, overlap with the target allowed. Each start runs with every strategy
through :mod:`deploy.experiments.compare`'s machinery (one lockstep pipeline per run,
results.json/csv, summary.md, figures), and every run that does not end on its goal gets
exactly one named cause; starts the pre-launch check refuses are counted with its reason.

Modules: :mod:`.starts` (the distribution and :func:`~.starts.draw_start`, each start from its
own generator, ``default_rng([seed, i])``: the same starts whatever N), :mod:`.causes` (one
named cause per run), :mod:`.report` (campaign.md, causes.json, starts.json), :mod:`.rates`
(how sure a success rate is: its Wilson interval), :mod:`.tally` (the runs counted per
strategy, for campaign.md and the docs' tables alike), all pure; and :mod:`.run` (draw, plan,
run and write a campaign). The command line is in :mod:`deploy.experiments.cli`.
"""
