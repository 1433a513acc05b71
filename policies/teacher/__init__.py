"""Teachers: the protocol (base.py) and the built-in implementations, registered by name."""

from msta.policies.teacher import gait, imported, rma  # noqa: F401  (registration)
