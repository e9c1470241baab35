"""What a run leaves and how it is read: the SQLite store (:mod:`.store`) with arrays beside it
(:mod:`.artifacts`), the leaderboard and its guards (:mod:`.leaderboard`, in a terminal:
:mod:`.board_table`), rate-distortion (:mod:`.rd`) and the HTML report (:mod:`.report`)."""
