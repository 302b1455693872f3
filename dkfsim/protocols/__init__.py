"""Exchange protocols: how the anti-delay DKF's contributions travel from node to node.

Importing this package registers the built-in protocols (``tree``, ``flood``).
"""

from dkfsim.protocols import tree, flood  # noqa: F401,I001  (registration, in this order)
