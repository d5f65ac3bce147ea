"""Pure I/O: one module per controller protocol behind one async interface
(`drivers.base.Driver`), and the simulated controllers and thermal plant in
`drivers.sim`."""
