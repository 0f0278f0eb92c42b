"""A run on the rig: the one stream of a run (listener, drive stream, AO writer), its safety limits
and pump interlock, the errors raised while running, its file and summary; the sweep
(`run.sweep`) and the operator programmes (`run.programs`) are the two kinds of run."""
