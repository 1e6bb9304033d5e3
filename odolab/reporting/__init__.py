"""What a comparison writes: tables, figures, HTML pages and trajectory files (`report`, `trajectory_plot`), and `run_comparison`, the compare pipeline end to end (`comparison`)."""
