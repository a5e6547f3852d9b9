"""The sensor stage, differentiable (placeholder until written)."""
