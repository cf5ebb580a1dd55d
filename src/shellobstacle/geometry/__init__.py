"""The shell's middle surface: safe expressions, θ's geometry, the theory's assumptions."""
