"""The target and its sensors: simulating the truth and the measurements of a run.

Importing this package registers the sensor kinds' implementations.
"""

from dkfsim.model import sensors, system  # noqa: F401  (registration)
