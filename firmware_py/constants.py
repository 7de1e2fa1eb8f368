"""Physical constants the controllers use.  firmware_py may not import plant_sim (the controllers know the
world through their inputs and these), so gravity is defined here once for them, as plant_sim.params
defines it once for the plant; the value is the same, 9.81 m/s², as the papers round it."""

G_MPS2 = 9.81        # standard gravity [m/s²]
