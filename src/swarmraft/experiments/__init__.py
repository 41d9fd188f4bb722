"""Monte Carlo sweeps, metrics and executors, built on the public APIs of the layers below."""

from swarmraft.experiments.compare import run_compare
from swarmraft.experiments.config import ConfigError, SweepConfig, build_config
from swarmraft.experiments.sweep import SweepResult, run_sweep

__all__ = ["ConfigError", "SweepConfig", "SweepResult", "build_config", "run_compare", "run_sweep"]
