"""Pictures for the human: the plan preview attached to every plan summary (`render`) and the
PNG and image helpers it and the camera reads share (`images`)."""
