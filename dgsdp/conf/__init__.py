"""The shipped Hydra configs (search path ``pkg://dgsdp.conf``); see :mod:`dgsdp.resources`."""
