"""The training engine shared by every trained method: run folders (:mod:`scapo.engine.runs`), one loop over a
schedule of stages (:mod:`scapo.engine.loop`), and data-parallel training under ``torchrun``
(:mod:`scapo.engine.distributed`). A method supplies its network, its training clouds and its losses."""

from scapo.engine.distributed import DistContext, dist_context
from scapo.engine.loop import CloudSet, FitConfig, Stage, TrainJob, fit, train_run
from scapo.engine.runs import RunFolder, plot_losses, read_checkpoint, read_run_json, resolve_device, truncate_log

__all__ = ["CloudSet", "DistContext", "FitConfig", "RunFolder", "Stage", "TrainJob", "dist_context", "fit",
           "plot_losses", "read_checkpoint", "read_run_json", "resolve_device", "train_run", "truncate_log"]
