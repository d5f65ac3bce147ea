"""Pure numerics of thermal error compensation: transfer functions, grey-box
ODE, MBOTV, compensation models (sums of terms), quality figures and
identification. No I/O, no event loop, no logging setup."""
