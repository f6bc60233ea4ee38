"""HTTP routes: thin wrappers over neural_shdf.api.engine.Engine and api/responses.py."""
