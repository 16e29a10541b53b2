"""Every label of the certificate, in English and Russian (one dict, one place).

``tr(lang)`` returns a callable ``t(key, **fields)``; a missing key is a bug and
raises ``KeyError`` (the tests render both languages, so every key used is checked).
"""

from __future__ import annotations

import re
from collections.abc import Callable

from chekan.errors import ChekanError
from chekan.report.labels_budget import BUDGET_LABELS
from chekan.report.labels_verdict import VERDICT_LABELS

#: A language's translator (:func:`tr`): ``t("key", field=value)`` → the text.
Translator = Callable[..., str]

LANGS = ("en", "ru")

LABELS: dict[str, dict[str, str]] = {
    # ------------------------------------------------------------------ title, header
    "title": {
        "en": "Calibration certificate",
        "ru": "Свидетельство о калибровке",
    },
    "subtitle": {
        "en": "{instrument} gravimeter, serial no. {serial} — tilt-method calibration protocol",
        "ru": "Гравиметр {instrument}, заводской № {serial} — протокол калибровки методом наклона",
    },
    "running_head": {
        "en": "{instrument} no. {serial} — calibration certificate",
        "ru": "{instrument} № {serial} — свидетельство о калибровке",
    },
    "page": {"en": "page", "ru": "стр."},
    "sec_header": {"en": "Instrument and calibration", "ru": "Прибор и условия калибровки"},
    "instrument": {"en": "Instrument", "ru": "Тип прибора"},
    "model_fmt": {"en": "{instrument} (model {model})", "ru": "{instrument} (модель {model})"},
    "serial": {"en": "Gravimeter serial no.", "ru": "Заводской номер гравиметра"},
    "platform_serial": {"en": "Gyro-platform serial no.", "ru": "Заводской номер УСГ"},
    "site": {"en": "Site", "ru": "Пункт калибровки"},
    "coords": {"en": "Coordinates", "ru": "Координаты"},
    "lat": {"en": "latitude", "ru": "широта"},
    "lon": {"en": "longitude", "ru": "долгота"},
    "height": {"en": "height {h} m", "ru": "высота {h} м"},
    "operator": {"en": "Operator", "ru": "Оператор"},
    "program": {"en": "Tilt program", "ru": "Программа наклонов"},
    "prog_rounds": {"en": "{n} round(s) about {axis}", "ru": "приёмов: {n}, наклоны вокруг {axis}"},
    "prog_rounds_each": {
        "en": "{n} rounds, each about its axis: {each}",
        "ru": "приёмов: {n}, ось наклона каждого: {each}",
    },
    "prog_angles": {"en": "angles {angles}", "ru": "углы {angles}"},
    "prog_angles_axis": {"en": "angles about {axis} {angles}", "ru": "углы вокруг {axis} {angles}"},
    "prog_dwell": {
        "en": "dwell {dwell} s (settling {settle} s)",
        "ru": "выдержка {dwell} с (успокоение {settle} с)",
    },
    "prog_dwell_only": {"en": "dwell {dwell} s", "ru": "выдержка {dwell} с"},
    "g_local": {"en": "Gravity at the site g", "ru": "Ускорение силы тяжести в пункте g"},
    "date": {"en": "Date of calibration", "ru": "Дата калибровки"},
    "started": {"en": "Record started (UTC)", "ru": "Начало записи (UTC)"},
    "method": {"en": "Method of estimation", "ru": "Метод обработки"},
    "method_classical": {
        "en": "classical least squares of eq. (21) on pair means (25), as Calibr.exe",
        "ru": "классический МНК по формуле (21) для средних отсчётов (25), как в Calibr.exe",
    },
    "method_map": {
        "en": "maximum a posteriori fit of the full forward model",
        "ru": "оценка максимума апостериорной плотности по полной модели",
    },
    "method_bayes": {
        "en": "Bayesian: posterior sampling of the full forward model",
        "ru": "байесовская: выборка из апостериорного распределения полной модели",
    },
    "input": {"en": "Input file", "ru": "Входной файл"},
    "input_record": {"en": "record (raw readings)", "ru": "запись (исходные отсчёты)"},
    "input_protocol": {
        "en": "legacy protocol table (Calibr.exe)",
        "ru": "таблица протокола (Calibr.exe)",
    },
    "sha": {"en": "SHA-256 of the input", "ru": "SHA-256 входного файла"},
    "software": {"en": "Software", "ru": "Программа"},
    "created": {"en": "Result computed (UTC)", "ru": "Расчёт выполнен (UTC)"},
    "level": {"en": "Level readings mₕ", "ru": "Отсчёты горизонта mₕ"},
    "ccd_center": {"en": "CCD centre m₀", "ru": "Центр ПЗС-линейки m₀"},
    "interval_prob": {"en": "Interval probability", "ru": "Доверительная вероятность"},
    "pix": {"en": "pix", "ru": "пикс"},
    "mgal": {"en": "mGal", "ru": "мГал"},
    "gal": {"en": "Gal", "ru": "Гал"},
    "yes": {"en": "yes", "ru": "да"},
    "no": {"en": "no", "ru": "нет"},
    "na": {"en": "n/a", "ru": "н/д"},
    # ------------------------------------------------------------------ items а)–е)
    "sec_a": {
        "en": "a) Reference and measured increments",
        "ru": "а) Заданные и измеренные приращения",
    },
    "sec_a_text": {
        "en": "Reference increments da_ref = g(1 − cos θ) and the increments dg measured by each "
        "quartz system in each round, for every tilt angle θ of the platform "
        "(± pair mean, eq. 25).",
        "ru": "Заданные приращения da_эт = g(1 − cos θ) и приращения dg, измеренные каждой "
        "кварцевой системой в каждом приёме, для каждого угла наклона θ гироплатформы "
        "(среднее пары ±, формула 25).",
    },
    "cap_a": {
        "en": "Reference increments da_ref and measured increments dg, mGal",
        "ru": "Заданные приращения da_эт и результаты измерений dg, мГал",
    },
    "angle": {"en": "Angle θ", "ru": "Угол θ"},
    "da_ref": {"en": "da_ref", "ru": "da_эт"},
    "round_n": {"en": "Round {n}", "ru": "Приём {n}"},
    "round": {"en": "Round", "ru": "Приём"},
    "sys_n": {"en": "S{n}", "ru": "КС{n}"},
    "system": {"en": "System", "ru": "Система"},
    "sec_b": {
        "en": "b) Deviations δg from the reference",
        "ru": "б) Отклонения δg от заданных значений",
    },
    "sec_b_text": {
        "en": "δg = da_ref − dg per angle, system and round; the last column is their mean Δg. "
        "RMS (СКП) is the root mean square of δg about its mean, per column.",
        "ru": "δg = da_эт − dg для каждого угла, системы и приёма; последний столбец — их "
        "среднее Δg. СКП — среднеквадратическое отклонение δg от среднего по столбцу.",
    },
    "cap_b": {"en": "Deviations δg, mGal", "ru": "Отклонения δg, мГал"},
    "cap_about": {"en": " — rounds about {axis}", "ru": " — приёмы с наклонами вокруг {axis}"},
    "sec_axis": {
        "en": "Rounds about {axis}: classical method, fitted apart",
        "ru": "Приёмы с наклонами вокруг {axis}: классический метод, отдельная обработка",
    },
    "sec_axis_text": {
        "en": "Rounds {rounds} tilt the platform about its X axis. They are processed as "
        "Calibr.exe processes a round (± pair mean, eq. 25; eqs. 21–24) and fitted apart, with "
        "their own a. They are not used by this certificate: da_ref = g(1 − cos θ) (eq. 14) is "
        "the response to tilts about Y; a tilt about X turns the pendulums in their own plane "
        "(eq. 6), which adds to the response a term of relative size about (gθ/bK)² "
        "(a quadratic coefficient about 5a).",
        "ru": "В приёмах {rounds} платформа наклоняется вокруг оси X. Они обработаны так же, "
        "как Calibr.exe обрабатывает приём (среднее пары ±, формула 25; формулы 21–24), "
        "отдельно, со своим a. В свидетельстве они не используются: da_эт = g(1 − cos θ) "
        "(формула 14) — отклик на наклоны вокруг Y; наклон вокруг X поворачивает маятники в "
        "их плоскости (формула 6), что добавляет к отклику член относительной величины около "
        "(gθ/bK)² (квадратичный коэффициент около 5a).",
    },
    "axis_fit": {
        "en": "Rounds about {axis} (not certified): {fit}",
        "ru": "Приёмы вокруг {axis} (не для свидетельства): {fit}",
    },
    "mean_dg": {"en": "Mean Δg", "ru": "Среднее Δg"},
    "rms_row": {"en": "RMS (СКП)", "ru": "СКП"},
    "pp_note": {
        "en": "Posterior-predictive 95 % band of δg per angle is shown in the residual figure.",
        "ru": "95-процентная апостериорно-прогнозная полоса δg показана на рисунке отклонений.",
    },
    "sec_c": {
        "en": "c) Reduced error of the calibration characteristic",
        "ru": "в) Приведённая погрешность градуировочной характеристики",
    },
    "sec_c_text": {
        "en": "The largest |mean δg| over the angles divided by the upper limit of the measuring "
        "range Δ₀ = 5 Gal.",
        "ru": "Отношение максимального по модулю среднего δg к верхнему пределу диапазона "
        "измерений Δ₀ = 5 Гал.",
    },
    "reduced_error": {
        "en": "Reduced error δg = {v} % (largest |mean δg| = {m} mGal at {angle})",
        "ru": "Приведённая погрешность δg = {v} % (максимальное |Δg| = {m} мГал при {angle})",
    },
    "sec_d": {
        "en": "d) Coefficients a, b₁, b₂ of the calibration characteristic",
        "ru": "г) Коэффициенты a, b₁, b₂ градуировочной характеристики",
    },
    "sec_d_text": {
        "en": "Characteristic Δg = b(m − mₕ) + a(m − mₕ)² (eq. 21); b is the scale factor at "
        "the level reading mₕ, b₀ = b + 2a(m₀ − mₕ) its value at the CCD centre m₀ (eq. 24).",
        "ru": "Характеристика Δg = b(m − mₕ) + a(m − mₕ)² (формула 21); b — масштабный "
        "коэффициент при отсчёте горизонта mₕ, b₀ = b + 2a(m₀ − mₕ) — его значение в центре "
        "ПЗС-линейки m₀ (формула 24).",
    },
    "cap_rounds": {
        "en": "Scale factors per round and system",
        "ru": "Масштабные коэффициенты по приёмам и системам",
    },
    "b_col": {"en": "b, mGal/pix", "ru": "b, мГал/пикс"},
    "u_col": {"en": "u(b)", "ru": "u(b)"},
    "b0_col": {"en": "b₀, mGal/pix", "ru": "b₀, мГал/пикс"},
    "mh_col": {"en": "mₕ, pix", "ru": "mₕ, пикс"},
    "rms_col": {"en": "RMS, mGal", "ru": "СКП, мГал"},
    "printed_col": {"en": "b (Calibr.exe)", "ru": "b (Calibr.exe)"},
    "cap_params": {
        "en": "Joint estimates over all rounds",
        "ru": "Совместные оценки по всем приёмам",
    },
    "cap_params_bayes": {
        "en": "Posterior summary: mean, standard deviation and {p} % HDI",
        "ru": "Апостериорные оценки: среднее, СКО и {p} %-й интервал наибольшей плотности",
    },
    "cap_params_tau": {
        "en": "τ is a parameter of the model, its u the fit's alone: the model holds each "
        "sample's attitude over the second before it, so a platform that moves within a "
        "sample or reports its angles late biases τ by many times u",
        "ru": "τ — параметр модели, его u — только от подгонки: модель считает положение "
        "платформы постоянным в течение секунды до отсчёта, поэтому платформа, движущаяся "
        "внутри отсчёта или выдающая углы с запаздыванием, смещает τ на много u",
    },
    "param": {"en": "Parameter", "ru": "Параметр"},
    "mean": {"en": "Estimate", "ru": "Оценка"},
    "sd": {"en": "u (1σ)", "ru": "u (1σ)"},
    "interval": {"en": "{p} % interval", "ru": "{p} %-й интервал"},
    "hdi": {"en": "{p} % HDI", "ru": "{p} % ИНП"},
    "unit": {"en": "Unit", "ru": "Ед."},
    "rhat": {"en": "R-hat", "ru": "R-hat"},
    "ess": {"en": "ESS", "ru": "ESS"},
    "fixed": {"en": "fixed", "ru": "фикс."},
    "mean_b": {
        "en": "Mean b over systems and rounds (Calibr.exe «Среднее»): {v} mGal/pix",
        "ru": "Среднее b по системам и приёмам: {v} мГал/пикс",
    },
    "discrepancy": {
        "en": "Discrepancy between rounds: {v} %",
        "ru": "Расхождение между приёмами: {v} %",
    },
    "a_convention": {
        "en": "a is given in the record convention (readings grow with gravity, tilts give "
        "m < mₕ); in the sign convention of Calibr.exe protocols a = {v} mGal/pix².",
        "ru": "a приведён в соглашении записи (отсчёт растёт с ростом силы тяжести, при наклоне "
        "m < mₕ); в соглашении протоколов Calibr.exe a = {v} мГал/пикс².",
    },
    "statement_title": {
        "en": "Scale factors with the expanded uncertainty U = k·u (coverage probability "
        "about 95 %):",
        "ru": "Масштабные коэффициенты с расширенной неопределённостью U = k·u "
        "(вероятность охвата около 95 %):",
    },
    "statement_title_repeat": {
        "en": "Scale factors with Calibr.exe's repeatability 2s (twice the least-squares "
        "standard error of eq. 21; not an expanded uncertainty):",
        "ru": "Масштабные коэффициенты с повторяемостью Calibr.exe 2s (удвоенная стандартная "
        "ошибка МНК по формуле 21; не расширенная неопределённость):",
    },
    "statement_repeat": {
        "en": "{name} = {x} {unit}, 2s = {u} {unit} (repeatability)",
        "ru": "{name} = {x} {unit}, 2s = {u} {unit} (повторяемость)",
    },
    "statement_typeA": {
        "en": "2s is twice the standard error of b from the scatter of this record's pair means "
        "about the least-squares fit, as Calibr.exe computes it: a repeatability, not an "
        "expanded uncertainty. The systematic error of the "
        "platform's angles, the sensor's lag, the drift and the hold offsets are not in it, "
        "and in the project's validation the interval b ± 2s held the true b in about 42 % of "
        "simulated sessions of the paper's program, not 95 %. No statement of conformity rests "
        "on it; the joint model (--method map or bayes) states b with an uncertainty budget "
        "and an expanded uncertainty.",
        "ru": "2s — удвоенная стандартная ошибка b по разбросу средних пар этой записи "
        "относительно подгонки МНК, как в Calibr.exe: повторяемость, а не расширенная "
        "неопределённость. В неё не входят систематическая "
        "погрешность углов платформы, запаздывание датчика, дрейф и смещения на стоянках; при "
        "проверке на моделированных записях программы статьи интервал b ± 2s содержал "
        "истинное b примерно в 42 % случаев, а не в 95 %. Заключение о соответствии на ней не "
        "основывается; совместная модель (--method map или bayes) даёт b с бюджетом "
        "неопределённости и расширенной неопределённостью.",
    },
    "statement_budget": {
        "en": "U = 2u with the combined standard uncertainty u of the budget "
        "(section «Uncertainty budget of b»).",
        "ru": "U = 2u, u — суммарная стандартная неопределённость по бюджету "
        "(раздел «Бюджет неопределённости b»).",
    },
    "statement_budget_t": {
        "en": "U = k·u with the combined standard uncertainty u of the budget (section "
        "«Uncertainty budget of b»); the Type A components rest on variances estimated "
        "from this record, so k is Student's t for 95.45 % at the effective degrees of "
        "freedom ν_eff (Welch–Satterthwaite, GUM G.4, G.6.4) instead of 2.",
        "ru": "U = k·u, u — суммарная стандартная неопределённость по бюджету (раздел "
        "«Бюджет неопределённости b»); составляющие типа А опираются на дисперсии, "
        "оценённые по этой записи, поэтому k — квантиль Стьюдента для 95,45 % при "
        "эффективном числе степеней свободы ν_eff (Уэлч — Саттертуэйт, GUM G.4, G.6.4), "
        "а не 2.",
    },
    "statement_budget_systematic": {
        "en": "U includes the systematic error of the platform's angle sensor (Type B, "
        "platform specification{bound}).",
        "ru": "U включает систематическую погрешность датчика угла платформы (тип В, "
        "паспорт платформы{bound}).",
    },
    "sec_e": {
        "en": "e) Deviations of b₁, b₂ from the initial values",
        "ru": "д) Отклонения b₁, b₂ от исходных значений",
    },
    "instability": {
        "en": "Instability of the scale factor {name}: δ{name} = {v} % (U = {u} %, k = {k}); "
        "initial {name} = {prior} mGal/pix",
        "ru": "Нестабильность масштабного коэффициента {name}: δ{name} = {v} % (U = {u} %, "
        "k = {k}); исходное {name} = {prior} мГал/пикс",
    },
    "instability_repeat": {
        "en": "Instability of the scale factor {name}: δ{name} = {v} % (2s = {u} %, Calibr.exe's "
        "repeatability, not an expanded uncertainty); initial {name} = {prior} mGal/pix",
        "ru": "Нестабильность масштабного коэффициента {name}: δ{name} = {v} % (2s = {u} %, "
        "повторяемость Calibr.exe, не расширенная неопределённость); исходное {name} = "
        "{prior} мГал/пикс",
    },
    "no_prior": {
        "en": "Not available: the input carries no initial scale factors (b1_prior, b2_prior).",
        "ru": "Нет данных: во входном файле нет исходных масштабных коэффициентов "
        "(b1_prior, b2_prior).",
    },
    "sec_f": {
        "en": "f) Margin of the measuring range",
        "ru": "е) Запас по диапазону измерений",
    },
    "margin_at": {
        "en": "Margin of the measuring range at latitude {lat}:",
        "ru": "Запас по диапазону измерений на широте {lat}:",
    },
    "margin_plain": {
        "en": "Margin of the measuring range at the calibration site:",
        "ru": "Запас по диапазону измерений в пункте калибровки:",
    },
    "margin_heavy": {
        "en": "{v} Gal towards heavier gravity",
        "ru": "{v} Гал — запас в тяжёлую сторону",
    },
    "margin_light": {
        "en": "{v} Gal towards lighter gravity",
        "ru": "{v} Гал — запас в лёгкую сторону",
    },
    "margin_ccd": {
        "en": "from the level readings to the CCD ends {lo}…{hi} pix, "
        "the smaller of the two systems.",
        "ru": "от отсчётов горизонта до краёв ПЗС-линейки {lo}…{hi} пикс, "
        "по меньшей из двух систем.",
    },
    "no_margin": {
        "en": "Not available: the input has no level readings (a protocol table).",
        "ru": "Нет данных: во входном файле нет отсчётов горизонта (таблица протокола).",
    },
    # ------------------------------------------------------------------ bayes, budget
    **BUDGET_LABELS,
    # ------------------------------------------------------------------ verdict, issue
    **VERDICT_LABELS,
    # ------------------------------------------------------------------ figures
    "sec_figures": {"en": "Figures", "ru": "Рисунки"},
    "fig_record": {
        "en": "The record: readings of both systems and the platform tilt over time; "
        "holds shaded (blue: level, orange: tilt), the settling part lighter.",
        "ru": "Запись: отсчёты обеих систем и наклон гироплатформы во времени; "
        "удержания закрашены (синие — горизонт, оранжевые — наклон), время успокоения светлее.",
    },
    "settled_note": {
        "en": "The hold means carried up to {pix} pix of the slews' transients (settling time "
        "{settle} s against the sensor's τ = {tau} s). Items a)–c), the classical b and the "
        "verdict use the hold means with the transient that the joint model fits removed. "
        "From the raw hold means, as Calibr.exe computes them: b₁ = {b1}, b₂ = {b2} mGal/pix, "
        "reduced error {rerr} %.",
        "ru": "Средние удержаний содержали до {pix} пикс переходного процесса после поворотов "
        "(время успокоения {settle} с при постоянной времени датчика τ = {tau} с). Пункты "
        "а)–в), классические b и заключение используют средние удержаний за вычетом "
        "переходного процесса, учтённого совместной моделью. По исходным средним, как в "
        "Calibr.exe: b₁ = {b1}, b₂ = {b2} мГал/пикс, приведённая погрешность {rerr} %.",
    },
    "transient_note": {
        "en": "The hold means still carry up to {pix} pix of the slews' transients (settling "
        "time {settle} s against the sensor's τ = {tau} s). The joint model fits them; the "
        "classical items a)–c) and the reduced error of the verdict, computed from the hold "
        "means as Calibr.exe computes them, are biased by them.",
        "ru": "Средние удержаний ещё содержат до {pix} пикс переходного процесса после "
        "поворотов (время успокоения {settle} с при постоянной времени датчика τ = {tau} с). "
        "Совместная модель его учитывает; классические пункты а)–в) и приведённая "
        "погрешность в заключении, вычисленные по средним удержаний как в Calibr.exe, им "
        "смещены.",
    },
    "fig_cos_lag": {
        "en": "The model's reading of a hold is its mean over the hold's settled samples with "
        "the sensor's lag τ followed through the record (a short settling time leaves part of "
        "the slew's transient in a hold mean).",
        "ru": "Отсчёт модели для удержания — его среднее по установившимся отсчётам удержания "
        "с запаздыванием датчика τ, прослеженным по всей записи (при коротком времени "
        "успокоения в среднем удержания остаётся часть переходного процесса после поворота).",
    },
    "fig_cos": {
        "en": "Readings against the tilt angle θ (the «cosinusoid», Fig. 3 of the paper): hold "
        "means and the fitted model's readings (the characteristic with the inclinations ε₁, "
        "ε₂{gamma} of the systems' axes). Below: each hold mean minus the model's reading at "
        "the angles measured in that hold, pix, against θ; shaded: {band}.",
        "ru": "Зависимость отсчётов от угла наклона θ («косинусоида», рис. 3 статьи): средние "
        "удержаний и отсчёты подобранной модели (характеристика с наклонами ε₁, ε₂{gamma} осей "
        "систем). Внизу: среднее каждого удержания минус отсчёт модели при углах, измеренных "
        "в этом удержании, пикс, в зависимости от θ; закрашено: {band}.",
    },
    "fig_cos_gamma": {"en": " and the azimuth Δγ", "ru": " и азимутом Δγ"},
    "fig_cos_band_model": {
        "en": "the model's 95 % band of a hold mean, ±2√(σ_hold² + (∂m/∂θ · σ_θ)²), with the "
        "fitted per-hold offset σ_hold and random angle readout σ_θ",
        "ru": "95 %-я полоса модели для среднего удержания, ±2√(σ_hold² + (∂m/∂θ · σ_θ)²), с "
        "оценёнными смещением удержания σ_hold и случайной ошибкой отсчёта угла σ_θ",
    },
    "fig_cos_band_rms": {
        "en": "±2 RMS of these residuals per system (the classical fit has no noise model)",
        "ru": "±2 СКП этих остатков по системам (у классической подгонки нет модели шума)",
    },
    "no_cos_model": {
        "en": "The figure of the readings against the angle is omitted: the result's a = {a} "
        "mGal/pix² is not positive, so it defines no pendulum model (a = g/(2K²)).",
        "ru": "Рисунок отсчётов в зависимости от угла не приводится: a = {a} мГал/пикс² в "
        "результате не положителен и не задаёт модели маятника (a = g/(2K²)).",
    },
    "fig_resid": {
        "en": "Deviations δg per angle for every round and system, their mean, and the "
        "tolerance ±{tol} % of 5 Gal.",
        "ru": "Отклонения δg по углам для каждого приёма и системы, их среднее и допуск "
        "±{tol} % от 5 Гал.",
    },
    "fig_resid_pp": {
        "en": " Bars: posterior-predictive 95 % band.",
        "ru": " Полосы: апостериорно-прогнозный 95 %-й интервал.",
    },
    "fig_pair": {
        "en": "Posterior pair plot (marginal histograms and pairwise scatter of the draws).",
        "ru": "Парные диаграммы апостериорного распределения (гистограммы и попарные выборки).",
    },
    "fig_drift": {
        "en": "Estimated drift of the readings with its 95 % band.",
        "ru": "Оценка дрейфа отсчётов и её 95 %-й интервал.",
    },
    "no_record_protocol": {
        "en": "The input is a protocol table without raw readings: the figures of the record "
        "and of the cosinusoid are omitted.",
        "ru": "Входной файл — таблица протокола без исходных отсчётов: рисунки записи и "
        "косинусоиды не приводятся.",
    },
    "no_record_file": {
        "en": "The record {path} is not available: the figures of the record and of the "
        "cosinusoid are omitted.",
        "ru": "Запись {path} недоступна: рисунки записи и косинусоиды не приводятся.",
    },
    "record_changed": {
        "en": "The record {path} differs from the calibrated one (SHA-256 mismatch): its figures "
        "are omitted.",
        "ru": "Запись {path} отличается от обработанной (не совпадает SHA-256): её рисунки не "
        "приводятся.",
    },
    "record_unreadable": {
        "en": "The record {path} could not be read ({err}): its figures are omitted.",
        "ru": "Запись {path} не читается ({err}): её рисунки не приводятся.",
    },
    "no_netcdf": {
        "en": "The posterior file {path} is not available: the pair plot is omitted.",
        "ru": "Файл апостериорной выборки {path} недоступен: парные диаграммы не приводятся.",
    },
    "bad_netcdf": {
        "en": "The posterior file {path} could not be read ({err}): the pair plot is omitted.",
        "ru": "Файл апостериорной выборки {path} не читается ({err}): парные диаграммы не "
        "приводятся.",
    },
    "footer_note": {
        "en": "Generated by chekan {version} from the result file of {created}. Equation numbers "
        "refer to the reference paper on the tilt-method calibration of the Chekan-AM.",
        "ru": "Сформировано программой chekan {version} по файлу результата от {created}. "
        "Номера формул — по статье о калибровке гравиметра «Чекан-АМ» методом наклона.",
    },
    "fig_label": {"en": "Figure {n}:", "ru": "Рис. {n}."},
    "tab_label": {"en": "Table {n}:", "ru": "Таблица {n}."},
    # figure axes
    "ax_time_h": {"en": "time, h", "ru": "время, ч"},
    "ax_reading": {"en": "reading m, pix", "ru": "отсчёт m, пикс"},
    "ax_tilt": {"en": "tilt, °", "ru": "наклон, °"},
    "ax_angle": {"en": "tilt angle θ, °", "ru": "угол наклона θ, °"},
    "ax_resid_pix": {"en": "hold mean − model, pix", "ru": "среднее − модель, пикс"},
    "ax_dg": {"en": "δg, mGal", "ru": "δg, мГал"},
    "ax_drift": {"en": "drift, pix", "ru": "дрейф, пикс"},
    "lg_s": {"en": "system {n}", "ru": "система {n}"},
    "lg_model": {"en": "fitted model", "ru": "модель"},
    "lg_model_axis": {"en": "fitted model, about {axis}", "ru": "модель, наклоны вокруг {axis}"},
    "lg_model_band": {"en": "95 % band", "ru": "95 %-я полоса"},
    "lg_rms_band": {"en": "±2 RMS", "ru": "±2 СКП"},
    "lg_mean": {"en": "mean Δg", "ru": "среднее Δg"},
    "lg_tol": {"en": "tolerance", "ru": "допуск"},
    "lg_level": {"en": "level", "ru": "горизонт"},
    "lg_tilt_x": {"en": "tilt X", "ru": "наклон X"},
    "lg_tilt_y": {"en": "tilt Y", "ru": "наклон Y"},
    "lg_band": {"en": "95 % band", "ru": "95 %-й интервал"},
    "lg_round": {"en": "round {n}", "ru": "приём {n}"},
    "lg_rounds": {"en": "rounds {a}–{b}", "ru": "приёмы {a}–{b}"},
    "cap_rounds_part": {"en": ", rounds {a}–{b}", "ru": ", приёмы {a}–{b}"},
}

# Parameter display names; units; known metadata values that have a Russian name.
PARAM_NAMES: dict[str, dict[str, str]] = {
    "b1": {"en": "b₁", "ru": "b₁"},
    "b2": {"en": "b₂", "ru": "b₂"},
    "a": {"en": "a", "ru": "a"},
    "b1_0": {"en": "b₁₀ (CCD centre)", "ru": "b₁₀ (центр ПЗС)"},
    "b2_0": {"en": "b₂₀ (CCD centre)", "ru": "b₂₀ (центр ПЗС)"},
    "eps1_arcmin": {"en": "ε₁", "ru": "ε₁"},
    "eps2_arcmin": {"en": "ε₂", "ru": "ε₂"},
    "dgamma_arcmin": {"en": "Δγ", "ru": "Δγ"},
    "tau_s": {"en": "τ (time constant)", "ru": "τ (постоянная времени)"},
    "drift1_pix_per_h": {"en": "drift of system 1", "ru": "дрейф системы 1"},
    "drift2_pix_per_h": {"en": "drift of system 2", "ru": "дрейф системы 2"},
    "sigma1_pix": {"en": "σ₁ (reading noise, system 1)", "ru": "σ₁ (шум отсчёта, система 1)"},
    "sigma2_pix": {"en": "σ₂ (reading noise, system 2)", "ru": "σ₂ (шум отсчёта, система 2)"},
    "sigma_theta_arcsec": {
        "en": "σ_θ (angle readout, random)",
        "ru": "σ_θ (отсчёт угла, случайная)",
    },
    "sigma_hold_pix": {
        "en": "σ_hold (per-hold offsets)",
        "ru": "σ_hold (смещения на стоянках)",
    },
    "slew_error": {"en": "κ (slew error, relative)", "ru": "κ (ошибка отработки наклона, отн.)"},
    "sigma_e_mgal": {
        "en": "σ_e (error of a pair mean)",
        "ru": "σ_e (погрешность среднего пары)",
    },
    "noise_scale": {"en": "s (noise scale)", "ru": "s (масштаб шума)"},
    "K": {"en": "K (optical conversion)", "ru": "K (оптическое преобразование)"},
}
UNITS: dict[str, dict[str, str]] = {
    "mGal/pix": {"en": "mGal/pix", "ru": "мГал/пикс"},
    "mGal/pix^2": {"en": "mGal/pix²", "ru": "мГал/пикс²"},
    "arcmin": {"en": "arcmin", "ru": "угл. мин"},
    "arcsec": {"en": "arcsec", "ru": "угл. с"},
    "s": {"en": "s", "ru": "с"},
    "pix/h": {"en": "pix/h", "ru": "пикс/ч"},
    "pix": {"en": "pix", "ru": "пикс"},
    "mGal": {"en": "mGal", "ru": "мГал"},
}
# a raw key as a whole word (not inside another name); single letters are words of the text
_RAW_NAME = re.compile(
    r"(?<![\w.])("
    + "|".join(re.escape(k) for k in sorted(PARAM_NAMES, key=len, reverse=True) if len(k) > 2)
    + r")(?![\w])"
)
VALUES: dict[str, dict[str, str]] = {
    "Chekan-AM": {"en": "Chekan-AM", "ru": "«Чекан-АМ»"},
    "Shelf": {"en": "Shelf", "ru": "Шельф"},
    "simulation": {"en": "simulation", "ru": "моделирование"},
}


# what the result's ``angle_sensor.source`` says (chekan.joint.angles), in Russian; a source
# of another form (a user's text) is printed as it is
_SOURCES_RU = (
    (
        re.compile(r"the paper's specification of the platform \((.+)\)"),
        "паспорт платформы по статье ({0})",
    ),
    (re.compile(r"(--angle-bound-arcsec)"), "параметр {0}"),
    (re.compile(r"header (\S+) of (.+)"), "заголовок {0} файла {1}"),
    (re.compile(r"angle calibration (.+) of (.+)"), "калибровка углов {0} от {1}"),
)


def source_name(source: str, lang: str) -> str:
    """An angle sensor's ``source`` (as :mod:`chekan.joint.angles` words it) in ``lang``."""
    if lang == "ru":
        for pattern, text in _SOURCES_RU:
            m = pattern.fullmatch(source)
            if m:
                return text.format(*m.groups())
    return source


def check_lang(lang: str) -> str:
    """``lang`` if supported, else a :class:`ChekanError` naming the choices."""
    if lang not in LANGS:
        raise ChekanError(f"unknown language {lang!r}; choose one of {', '.join(LANGS)}")
    return lang


def tr(lang: str) -> Translator:
    """The translator for ``lang``: ``t("key", field=value)``."""
    check_lang(lang)

    def t(key: str, **fields: object) -> str:
        text = LABELS[key][lang]
        return text.format(**fields) if fields else text

    return t


def param_name(name: str, lang: str) -> str:
    """Display name of a result parameter (the raw key when unknown)."""
    return PARAM_NAMES.get(name, {}).get(lang, name)


def with_param_names(text: str, lang: str) -> str:
    """``text`` (a message of the fit) with every raw parameter key (``eps1_arcmin``,
    ``sigma1_pix`` …) replaced by its display name."""
    return _RAW_NAME.sub(lambda m: PARAM_NAMES[m.group(0)][lang], text)


def unit_name(unit: str, lang: str) -> str:
    """Display form of a unit string of the result (as is when unknown)."""
    return UNITS.get(unit, {}).get(lang, unit)


def value_name(value: str, lang: str) -> str:
    """Localised form of a known metadata value (instrument, model); others unchanged."""
    return VALUES.get(value, {}).get(lang, value)
