"""What a person reads: tables and figures of run, Monte Carlo and sweep folders."""
