"""Reports on a study or bench folder: summaries and break points (:mod:`.summary`), charts
(:mod:`.charts`), the paper's tables (:mod:`.tables`), paired comparisons of two methods
(:mod:`.paired`), two folders side by side (:mod:`.compare`) and one self-contained HTML page
(:mod:`.report`)."""
