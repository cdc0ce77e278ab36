"""From samples to positions: the static-window detector, its noise floor, window statistics, the noise model (Allan), the slews between windows and unit plausibility."""
