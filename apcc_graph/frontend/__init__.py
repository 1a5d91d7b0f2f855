"""Image front end: feature tracks from tip-camera images (:mod:`apcc_graph.frontend.tracking`)."""
