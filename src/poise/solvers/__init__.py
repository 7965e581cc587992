"""Solvers: FIM_S (Newton), FIM_D (DAE continuation), MKEAM (kinetic-energy attrition)."""
