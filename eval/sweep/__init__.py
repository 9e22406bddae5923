"""Many runs: a sweep spec expanded into jobs, run once each (shared stages, shared
decisions, resumable), kept in a SQLite store, searched with Optuna, summarised per family
over seeds and plotted."""
