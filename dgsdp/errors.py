"""Errors a user can meet. Each message says what is wrong and what to do about it."""


class DgsdpError(Exception):
    """Base class for errors caused by user input (files, configs, weights), not by bugs."""


class DataError(DgsdpError):
    """A dataset file or folder is missing, unreadable or malformed."""


class AudioError(DgsdpError):
    """An audio file cannot be decoded or is unusable (empty, too short)."""


class WeightsError(DgsdpError):
    """Pretrained weights are missing or do not match the configured model."""


class ConfigError(DgsdpError):
    """A configuration value is invalid or inconsistent with a checkpoint."""


class CheckpointError(ConfigError):
    """A checkpoint cannot be used: unreadable, not one of ours, or its stored config asks for something other
    than the project's own classes (a checkpoint's config is data, never code)."""


class UnsafeCheckpointError(CheckpointError):
    """A checkpoint file asks for a Python global that the weights-only loader does not allow (it could run code)."""
