"""The network shared by every estimator of a run: links (propagation), media (how a frame
leaves its sender), ports (one per estimator: numbering, counting, delivering) and the network
that ties them (docs/design.md §3; docs/architecture.md, "The network layer")."""
