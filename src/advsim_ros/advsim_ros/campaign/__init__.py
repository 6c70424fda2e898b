"""Campaigns: many attacks (scenario windows x stacks x algorithms x actors x objectives x seeds) on Ray.

campaign.config reads and checks the campaign YAML and expands it into attacks; campaign.schedule
runs them as Ray tasks, each one isolated graph, with a journal that makes the campaign resumable;
campaign.results turns each attack's summary.json into a row; campaign.report writes results.csv,
report.md and report.html (the paper's tables); campaign.suite exports found failures as a
regression suite that `advsim regress` replays.
"""
