"""The benchmark: the pipeline, paired statistics, targets, stamps and lock, the watch GIF and the 2-D
tasks."""
