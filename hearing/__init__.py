"""Hearing and speaking: what a robot's Core and the Platform do with sound, on 16 kHz int16 samples,
whatever records them (a simulated house, a real robot's microphones). Nothing here imports the
simulator: robots/ renders the house's sound and plays the loudspeaker, and uses this package.

    vad.py        VoiceActivity: utterances cut from a stream; HeardUtterance; speech_segments
    bands.py      band spectra of 10 ms frames (the detector's spectral-shape test)
    steering.py   a microphone array: locate, MVDR, the detector's filter, Steering beside a detector
    decoder.py    PhraseDecoder: pocketsphinx grammar search checked against a free phone loop
    keywords.py   KeywordSpotter, said_alone, keyword_in_a_sentence, WordSpotter, LookAhead: the one
                  place that decides whether a keyword was said (its threshold: ACCEPT)
    pronounce.py  eSpeak NG's pronunciation of words outside the recogniser's dictionary
    tts.py        text to speech (eSpeak NG)
    wav.py        WAV in and out, a recording's level
    errors.py     HearingError and its kinds, each with a wire `code`
    blas.py       one BLAS thread per process (run on import, below)

docs/sound.md says what was measured with them, and what the simulation makes easier than a room.
"""
from .blas import one_blas_thread

one_blas_thread()  # before numpy is used from several threads (hearing/blas.py)
