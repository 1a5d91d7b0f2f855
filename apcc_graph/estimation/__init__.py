"""Estimators of the segment angles over a sequence: the paper's chain (front end only); the
factor-graph batch optimiser and fixed-lag smoother build on it."""
