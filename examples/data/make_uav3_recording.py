"""Write examples/data/uav-3-ros.mcap: a small ROS 2 recording of three UAVs (run it to make it again).

The recording of the guide's "ROS 2 recordings" page, written with mcap-ros2-support's Writer (no ROS
installed; ``pip install 'teamkf[ros]'``): a simulated run of examples/scenarios/uav-3-ros.toml, 60 steps of
0.1 s (altitudes are deviations from the formation's, in m), with header stamps jittered by up to 20 ms and logged 30 ms later; GPS altitudes
(geometry_msgs/msg/PointStamped, point.z), rangefinder altitudes (sensor_msgs/msg/Range, range), and the true
altitudes (std_msgs/msg/Float64MultiArray on /sim/altitude). UAV 1's GPS drops out for
steps 20-24.
"""

from pathlib import Path

import numpy as np
from mcap_ros2.writer import Writer

from teamkf import load_scenario, sample

HERE = Path(__file__).resolve().parent
SEP = "=" * 80
HEADER = (
    f"{SEP}\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n{SEP}\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
)
POINT_STAMPED = f"std_msgs/Header header\ngeometry_msgs/Point point\n{SEP}\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n" + HEADER
RANGE = (
    "uint8 ULTRASOUND=0\nuint8 INFRARED=1\nstd_msgs/Header header\nuint8 radiation_type\nfloat32 field_of_view\n"
    "float32 min_range\nfloat32 max_range\nfloat32 range\n" + HEADER
)
MULTI_ARRAY = (
    f"std_msgs/MultiArrayLayout layout\nfloat64[] data\n{SEP}\nMSG: std_msgs/MultiArrayLayout\nstd_msgs/MultiArrayDimension[] dim\n"
    f"uint32 data_offset\n{SEP}\nMSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n"
)
START, PERIOD, T = 1_700_000_000 * 10**9, 100_000_000, 60  # ns, ns, steps


def main(path: Path = HERE / "uav-3-ros.mcap") -> None:
    sc = load_scenario(str(HERE.parent / "scenarios" / "uav-3-ros.toml"))
    x, y = sample(sc.system, T, 1, rng=2026)
    x, y = x[0], [yi[0] for yi in y]
    rng = np.random.default_rng(7)
    msgs = []

    def stamp(t: int) -> dict:
        return {"sec": t // 10**9, "nanosec": t % 10**9}

    for k in range(T):
        for topic, value, kind in (
            ("/uav0/gps", y[0][k, 0], "gps"),
            ("/uav0/range", y[0][k, 1], "range"),
            ("/uav1/gps", y[1][k, 0], "gps"),
            ("/uav2/range", y[2][k, 0], "range"),
        ):
            if topic == "/uav1/gps" and 20 <= k < 25:
                continue  # the GPS dropped out
            t = START + k * PERIOD + int(rng.integers(-20_000_000, 20_000_000))
            head = {"stamp": stamp(t), "frame_id": topic.split("/")[1]}
            if kind == "gps":
                msg = {"header": head, "point": {"x": 0.0, "y": 0.0, "z": float(value)}}
            else:  # float32 on the wire: the recorded value is what the filter reads
                msg = {"header": head, "radiation_type": 1, "field_of_view": 0.05, "min_range": 0.1, "max_range": 40.0, "range": float(value)}
            msgs.append((t + 30_000_000, topic, kind, msg))
        t = START + k * PERIOD + int(rng.integers(-5_000_000, 5_000_000))  # the simulator's truth, no header: its log time
        msgs.append((t, "/sim/altitude", "array", {"layout": {"dim": [], "data_offset": 0}, "data": [float(v) for v in x[k]]}))
    msgs.sort(key=lambda m: m[0])
    with open(path, "wb") as fh:
        w = Writer(fh)
        schemas = {
            "gps": w.register_msgdef("geometry_msgs/msg/PointStamped", POINT_STAMPED),
            "range": w.register_msgdef("sensor_msgs/msg/Range", RANGE),
            "array": w.register_msgdef("std_msgs/msg/Float64MultiArray", MULTI_ARRAY),
        }
        for t, topic, kind, msg in msgs:
            w.write_message(topic, schemas[kind], msg, log_time=t, publish_time=t)
        w.finish()
    print(f"written {path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
