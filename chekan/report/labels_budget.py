"""The certificate's labels of the Bayesian result and its uncertainty budget, in English
and Russian: a part of :data:`chekan.report.i18n.LABELS` (kept apart to keep that table
short; every key is reached through :func:`chekan.report.i18n.tr`)."""

from __future__ import annotations

BUDGET_LABELS: dict[str, dict[str, str]] = {
    "sec_budget": {"en": "Uncertainty budget of b", "ru": "Бюджет неопределённости b"},
    "budget_text": {
        "en": "Standard uncertainties of each source, from the posterior; relative values in ppm "
        "(10⁻⁶). Type A: evaluated from the scatter of the data; Type B: from other "
        "information (the platform's specification, prior knowledge).",
        "ru": "Стандартные неопределённости по источникам, по апостериорному распределению; "
        "относительные значения в млн⁻¹ (10⁻⁶). Тип А — оценка по разбросу данных; "
        "тип В — по иной информации (паспорт платформы, априорные сведения).",
    },
    "cap_budget": {
        "en": "Uncertainty budget of the scale factors, mGal/pix",
        "ru": "Бюджет неопределённости масштабных коэффициентов, мГал/пикс",
    },
    "source": {"en": "Source", "ru": "Источник"},
    "ppm": {"en": "ppm", "ru": "млн⁻¹"},
    "src_type": {"en": "Type", "ru": "Тип"},
    "type_A": {"en": "A", "ru": "А"},
    "type_B": {"en": "B", "ru": "В"},
    "src_angle_readout": {
        "en": "angle readout, random (Type A)",
        "ru": "отсчёт угла, случайная (тип А)",
    },
    "src_angle_systematic": {  # bound: " ±3″" or "" when the result does not say
        "en": "angle sensor, systematic (Type B, platform specification{bound})",
        "ru": "датчик угла, систематическая (тип В, паспорт платформы{bound})",
    },
    "src_angle_systematic_axis": {
        "en": "angle sensor {axis}, systematic",
        "ru": "датчик угла {axis}, систематическая",
    },
    "src_angle_systematic_xy": {
        "en": "angle sensors X and Y, the scale error they may share (Type B, the smaller u)",
        "ru": "датчики угла X и Y, возможная общая ошибка масштаба (тип В, по меньшей u)",
    },
    "src_angle_spec_of": {
        "en": " (Type B, platform specification{bound})",
        "ru": " (тип В, паспорт платформы{bound})",
    },
    "src_angle_cal_of": {
        "en": " (Type B, angle calibration {id})",
        "ru": " (тип В, калибровка углов {id})",
    },
    "src_x_response": {
        "en": "response to tilts about X beyond eq. (6) (Type B, eq. 20: 0.2 mGal) and the "
        "pendulums' horizontal (Type B, CCD centre, sd {u} pix)",
        "ru": "отклик на наклоны вокруг X сверх ур. (6) (тип В, ур. 20: 0,2 мГал) и "
        "горизонтальное положение маятников (тип В, центр ПЗС, ско {u} пикс)",
    },
    "src_angle_systematic_cal": {
        "en": "angle sensor, systematic (Type B, angle calibration {id})",
        "ru": "датчик угла, систематическая (тип В, калибровка углов {id})",
    },
    "angle_sensor": {"en": "Platform angle sensor", "ru": "Датчик угла платформы"},
    "angle_calibration": {"en": "Angle calibration", "ru": "Калибровка углов платформы"},
    "angle_calibration_text": {
        "en": "{id} of {date}{lab}: corrections applied to the measured angles, "
        "their U (k = 2) replaces the specification",
        "ru": "{id} от {date}{lab}: поправки внесены в измеренные углы, "
        "их U (k = 2) заменяет паспортную границу",
    },
    "angle_sensor_calibrated": {
        "en": "from its calibration: u per angle up to {ua}″, scale u = {us}″ at the largest angle",
        "ru": "по калибровке: u по углу до {ua}″, u масштаба = {us}″ на наибольшем угле",
    },
    "angle_sensor_calibrated_stated": {
        "en": "from its calibration, which states its scale part: u per angle up to {ua}″, "
        "scale u = {us}″ at the largest angle",
        "ru": "по калибровке с указанной в ней долей масштаба: u по углу до {ua}″, "
        "u масштаба = {us}″ на наибольшем угле",
    },
    "angle_source": {"en": "source: {src}", "ru": "источник: {src}"},
    "dist_triangular": {"en": "triangular", "ru": "треугольное распределение"},
    "dist_rectangular": {"en": "rectangular", "ru": "равномерное распределение"},
    "angle_sensor_systematic": {
        "en": "bound ±{u}″ read as {dist}, per-angle u = {ua}″, scale u = {us}″ at the largest "
        "angle",
        "ru": "граница ±{u}″, {dist}, u по углу = {ua}″, u масштаба = {us}″ на наибольшем угле",
    },
    "dist_rectangular_gum": {
        "en": "rectangular (u = U/√3, GUM 4.3.7: only a bound is known)",
        "ru": "равномерное распределение (u = U/√3, GUM 4.3.7: известна лишь граница)",
    },
    "dist_triangular_gum": {
        "en": "triangular (u = U/√6, GUM 4.3.9)",
        "ru": "треугольное распределение (u = U/√6, GUM 4.3.9)",
    },
    "angle_sensor_independent": {
        "en": "errors independent from hold to hold (no systematic term)",
        "ru": "погрешности независимы от стоянки к стоянке (без систематической составляющей)",
    },
    "src_noise": {"en": "reading noise", "ru": "шум отсчёта"},
    "src_drift": {"en": "drift", "ru": "дрейф"},
    "src_a": {"en": "quadratic coefficient a", "ru": "квадратичный коэффициент a"},
    "src_hold_offsets": {
        "en": "per-hold offsets of the quartz systems",
        "ru": "смещения кварцевых систем на стоянках",
    },
    "src_level_offset": {"en": "level reading", "ru": "отсчёт в горизонте"},
    "src_other_priors": {"en": "other priors (ε, γ, τ, b)", "ru": "прочие априорные (ε, γ, τ, b)"},
    "src_total": {"en": "combined standard uncertainty u", "ru": "суммарная стандартная u"},
    "src_expanded_k2": {"en": "expanded U (k = 2)", "ru": "расширенная U (k = 2)"},
    "src_expanded": {"en": "expanded U = k·u", "ru": "расширенная U = k·u"},
    "src_coverage_factor": {
        "en": "coverage factor k (95.45 %)",
        "ru": "коэффициент охвата k (95,45 %)",
    },
    "src_nu_eff": {
        "en": "effective degrees of freedom ν_eff",
        "ru": "эффективное число степеней свободы ν_eff",
    },
    "src_hyperparameters": {
        "en": "variances estimated from the record (σ_θ, σ_o, noise)",
        "ru": "дисперсии, оценённые по записи (σ_θ, σ_o, шум)",
    },
    "sec_diag": {"en": "Convergence diagnostics", "ru": "Диагностика сходимости"},
    "sec_diag_classical": {"en": "Fit diagnostics", "ru": "Диагностика подгонки"},
    "converged": {"en": "Converged", "ru": "Сходимость"},
    "rhat_max": {
        "en": "Largest R-hat (should be < 1.01)",
        "ru": "Наибольший R-hat (должен быть < 1.01)",
    },
    "sampler": {"en": "Posterior drawn by", "ru": "Апостериорная выборка"},
    "sampler_importance": {
        "en": "importance sampling from the fitted proposal (Pareto k = {k}, smallest ESS {ess})",
        "ru": "выборка по значимости из подобранного распределения (k Парето = {k}, "
        "наименьший ESS {ess})",
    },
    "sampler_emcee": {"en": "emcee (ensemble MCMC)", "ru": "emcee (ансамблевый MCMC)"},
    "sampler_refused": {
        "en": "emcee (ensemble MCMC): importance sampling was not reliable (Pareto k = {k}, "
        "smallest ESS {ess})",
        "ru": "emcee (ансамблевый MCMC): выборка по значимости ненадёжна (k Парето = {k}, "
        "наименьший ESS {ess})",
    },
    "ess_min": {
        "en": "Smallest bulk ESS (should be ≥ 400)",
        "ru": "Наименьший ESS (должен быть ≥ 400)",
    },
    "n_draws": {"en": "Posterior draws", "ru": "Число выборок"},
    "seconds": {  # the whole estimate's wall time: map samples nothing; compiling is in it
        "en": "Computing time (compiling included), s",
        "ru": "Время расчёта (включая компиляцию), с",
    },
    "sigma_fit": {"en": "Residual sd of the fit σ, mGal", "ru": "СКО остатков подгонки σ, мГал"},
    "problem": {"en": "Problem", "ru": "Проблема"},
    "note": {"en": "Note", "ru": "Примечание"},
    "messages_in_english": {
        "en": "The estimator's messages below are in English, as chekan writes them.",
        "ru": "Сообщения программы оценивания ниже приводятся на английском языке, как их "
        "выдаёт программа (chekan); обозначения параметров даны по-русски.",
    },
}
