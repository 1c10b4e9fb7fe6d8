"""simreel.options: each option of a command declared once (`declare`), and the checks of values a Python caller
gives (`checks`)."""
