"""Pure numerics of thermal error compensation: transfer functions, grey-box
ODE, MBOTV, compensation models (sums of terms), quality figures,
identification and the probe-assisted adaptation estimator. No I/O, no event
loop, no logging setup."""
