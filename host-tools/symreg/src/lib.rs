//! Deterministic parallel symbolic regression: islands, Pareto front, constant optimisation, model selection.
#![deny(missing_docs)]
