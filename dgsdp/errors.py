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
    """A checkpoint cannot be used: unreadable, not ours, from another configuration, or asking to build
    something that is not one of the project's own classes."""
