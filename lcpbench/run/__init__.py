"""Run machinery: sweep specifications, the runner, the run store and the executors."""
