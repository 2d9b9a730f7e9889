"""Per-call cost of the simulated world's hot paths (prints figures; no assertions)."""
import timeit
import numpy as np
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from companion.sensor_wire import encode_reading
from sitl_mock.sensor import SignalSensor
from sitl_mock.faults import FaultSet
from sitl_mock.fields_gaussian import sigma1

def flying(**kw):
    m = Multicopter(DynamicsParams(**kw), np.random.default_rng(1)); m.arm(); m.command_takeoff(10)
    for _ in range(1000): m.step(0.02)
    return m

N = 100000
cases = [("idle on ground", None, {}), ("hover", "hover", {}), ("cruise 10 m/s", (1e5, 0, -10), {}),
         ("cruise + wind + gusts + gps noise", (1e5, 0, -10),
          dict(wind_ned_m_s=(3, 2, 0), wind_gust_std_m_s=1.0, gps_noise_std_m=0.5))]
for label, tgt, kw in cases:
    if tgt is None:
        m = Multicopter(DynamicsParams(**kw), np.random.default_rng(1)); m.arm()
    else:
        m = flying(**kw)
        if tgt != "hover": m.command_position(tgt)
    t = timeit.timeit(lambda: m.step(0.02), number=N) / N
    print(f"Multicopter.step(0.02) {label:36s}: {t*1e6:6.2f} us  -> 100 vehicles at 50 Hz: {t*100*50*100:5.2f} % of a core")
m = flying(gps_noise_std_m=0.5)
print(f"reported_position_ned_m: {timeit.timeit(m.reported_position_ned_m, number=N)/N*1e6:.2f} us")
print(f"position_ned_m         : {timeit.timeit(lambda: m.position_ned_m, number=N)/N*1e6:.2f} us")
s = SignalSensor(sigma1(), 0.1, np.random.default_rng(0), FaultSet(), "swarmseek", 1)
pos = np.array([1.0, 2.0, 3.0])
t = timeit.timeit(lambda: s.sample(1.7e9, pos, 45.0, 5.0, 230.0), number=N // 5) / (N // 5)
print(f"SignalSensor.sample    : {t*1e6:.2f} us")
r = s.sample(1.7e9, pos, 45.0, 5.0, 230.0)
print(f"encode_reading         : {timeit.timeit(lambda: encode_reading(r), number=N//5)/(N//5)*1e6:.2f} us")
