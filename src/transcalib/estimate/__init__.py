"""Estimators: the paper's linear TLS (:mod:`.linear`), robust estimation
(:mod:`.robust`) and the one bundle adjuster with its covariance (:mod:`.refine`)."""
