"""vitac's Hydra plugin: the sweeper that checks every job of a multirun before the first starts. Hydra loads
sweepers only from the `hydra_plugins` namespace package, hence this package beside `vitac/`."""
