"""Reading runs: learning curves, summaries, evaluation outcomes, the action noise (`python -m vitac.runs`)."""
