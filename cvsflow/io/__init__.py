"""File formats at the edge: everything cvsflow reads or writes goes through here."""

from cvsflow.io.files import (
           atomic_output,
           read_csv_table,
           read_parquet,
           read_yaml,
           save_figure,
           write_parquet,
           write_yaml,
)

__all__ = ["atomic_output", "read_csv_table", "read_parquet", "read_yaml", "save_figure", "write_parquet",
           "write_yaml"]
