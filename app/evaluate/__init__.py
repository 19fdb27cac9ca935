"""`splatstyler eval`: the evaluation grid (grid file, jobs, local or Ray runner, report)."""
