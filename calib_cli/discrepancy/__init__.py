"""The discrepancy loop (SPEC section 6): compare the calibrated model with the measurements
per condition, and rank the missing effects by how much of the misfit each would explain."""
