"""The error models, their coefficients and files: terms, triad models, coefficient sets (versioned), reference magnitudes, effect plug-ins, static positions."""
