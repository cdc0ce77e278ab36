"""What coefficients do to navigation: the strapdown INS error model, free-inertial navigation of recordings, trajectories and alignment."""
