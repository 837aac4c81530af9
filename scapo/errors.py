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
