"""Exception types. Every error names the offending thing and, where possible, what to do."""

from __future__ import annotations


class ScapoError(Exception):
    """Base class of all errors raised deliberately by scapo."""


class UnknownNameError(ScapoError, KeyError):
    """A registry lookup used a name that is not registered (the message lists the known names)."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


class ConfigError(ScapoError, ValueError):
    """A configuration value is invalid or conflicts with data already on disk."""


class BudgetError(ConfigError):
    """A trained cell charged more than its budget allows (:func:`scapo.engine.ledger.check_budget`); its run is kept,
    no record is written."""


class StaleAssetsError(ConfigError):
    """A dataset folder's finished shards were rendered from other assets than the current ones (the asset
    generator or its templates changed since): resuming would mix two versions of the objects."""


class AssetError(ScapoError):
    """An articulated asset (URDF + meshes) is malformed or incomplete."""


class URDFError(AssetError):
    """A URDF file cannot be parsed or violates what the loader supports."""


class MissingMeshError(AssetError, FileNotFoundError):
    """A URDF names a mesh file that does not exist."""


class RenderError(ScapoError):
    """Rendering failed (no Vulkan device, or SAPIEN returned unusable pictures)."""


class RejectedViewError(ScapoError):
    """A sampled view does not satisfy the visibility requirements (counted, then resampled)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class DatasetError(ScapoError):
    """A dataset directory is missing, incomplete or inconsistent."""


class CorruptShardError(DatasetError):
    """A dataset shard cannot be read or fails its checksum (the message names the shard)."""


class PredictionError(ScapoError, ValueError):
    """A predictions file is malformed or does not match the dataset it is evaluated on."""


class OutputError(ScapoError):
    """An output path cannot be used (a folder where a file is expected, not writable, locked by another
    process); raised before any long work starts."""


class InputError(ScapoError, ValueError):
    """Input data given to the Python API (point clouds, arrays) is malformed or out of the accepted range."""


class TrainingError(ScapoError):
    """Training cannot continue (NaN/inf loss, incompatible checkpoint); the message names the cause."""


class ScapoWarning(UserWarning):
    """Something the user should know that does not stop the command (e.g. too few instances for a statistic);
    the CLI prints it as ``scapo <command>: warning: ...``."""


#: fewer instances than this in a split make its scores (or a model trained on it) unreliable: a warning says so
MIN_INSTANCES = 5


def warn_few_instances(n: int, split: str, root, what: str) -> None:
    """Warn (:class:`ScapoWarning`) when a split holds fewer than :data:`MIN_INSTANCES` instances."""
    if n < MIN_INSTANCES:
        import warnings

        warnings.warn(f"the {split} split of {root} holds only {n} instance(s) (views of one object are not "
                      f"independent): {what} rest on too few objects to rank methods; generate at least "
                      f"{MIN_INSTANCES} (better 30)", ScapoWarning, stacklevel=3)
