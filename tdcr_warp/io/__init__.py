"""Files and pictures: scenes (TOML) to model objects, sweep stores (Parquet/Zarr), figures,
animations and the HTML viewer. Reads and writes data; never solves."""
