"""What only a fleet can know (issue 28): how fast each coefficient of a model ages.

    recal.fleet.history   accepted versions of many units as flat arrays -> their changes
    recal.fleet.estimate  random-walk ageing rate per coefficient, by maximum likelihood
    recal.fleet.prior     FleetPrior: the versioned figure sent back to the vessels
    recal.fleet.outliers  units whose changes are outliers for their model (chi-square)
    recal.fleet.compute   fleet_prior(): versions -> FleetPrior, outliers set aside
    recal.fleet.simulate  a simulated ageing fleet with known spreads

Pure numerics: text and arrays in, objects out (the files are read and written by the service).
"""
