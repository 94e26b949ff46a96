"""bayes_mr: Bayesian identification, selection and diagnosis of MR-damper models."""

__version__ = "0.1.0"
