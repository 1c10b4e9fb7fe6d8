"""LeRobot dataset v3.0, written from simreel recordings (`simreel export ... --to lerobot OUT`): the layout and
its metadata (`layout`), the per-frame columns made from an episode's rows (`frames`), and the export that streams
episodes into many-episode parquet files and writes the metadata once at the end (`export`)."""
